"""The files and figures of a loading path (docs/evolution.md): one ``solution_NNN.vtu``
per step and the ParaView collection ``path.pvd`` that plays them, the path's
``summary.json`` record, and the two figures read off a load-displacement loop (the
residual imprint and the initial elastic unloading slope).

The plot itself is drawn by :func:`elastoplast.plots.figures.plot_path`; this
module only computes and writes what it is given.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from elastoplast.certificate.indentation import indentation_summary, symmetry_share
from elastoplast.certificate.oliver_pharr import SHAPES, oliver_pharr
from elastoplast.certificate.solution import Solution, Status, contact_radius, summary
from elastoplast.fem.discretize import Discretization
from elastoplast.io.output import write_vtu
from elastoplast.solvers.path import YIELD_STRAIN_SHARE, PathResult, PathStep

#: the name of the collection that plays a path's steps in ParaView
PVD_NAME = "path.pvd"


def step_file_name(index: int, n_steps: int) -> str:
    """``solution_001.vtu``: the step's number, zero-padded to three digits (more
    when the path has more than 999 steps, so that the names sort in order)."""
    return f"solution_{index:0{max(3, len(str(n_steps)))}d}.vtu"


def path_status(result: PathResult) -> tuple[Status, str]:
    """The status of a whole path and why: ``converged`` when every step converged,
    else the status of the step that did not (the path stops there)."""
    n = len(result.forces)
    if result.converged:
        return Status.CONVERGED, f"{n} of {n} steps converged"
    bad = next((s for s in result.steps if not s.converged), None)
    if bad is None:  # every step run converged: the time limit stopped the path
        return Status.TIME_LIMIT, result.stopped or f"{len(result.steps)} of {n} steps run"
    return bad.status, (f"step {bad.index} of {n} (F = {bad.force:g}) ended {bad.status.value}: "
                        f"{bad.solution.message}; the path stops there")


def path_solution(result: PathResult) -> Solution:
    """The path's answer as one :class:`Solution`: the last step's stresses and
    contact forces with the *total* displacement ``u``, the path's status and message
    (:func:`path_status`), every step's iterations summed and the path's time as
    ``timings["total"]``. Its certificate is the last step's, judged by that step's
    problem (not by Hencky's at the same force)."""
    last = result.steps[-1]
    status, message = path_status(result)
    return replace(last.solution, u=last.u, status=status, message=message,
                   iterations=sum(s.solution.iterations for s in result.steps),
                   timings={"total": float(result.time_s)}, history=[])


#: a slope read off an unloading needs its first step to move U by this many times the
#: accuracy the answers' certificates give U (below it, the slope is their round-off)
SLOPE_RESOLUTION = 1e3


def first_unloading_step(result: PathResult) -> tuple[PathStep, PathStep] | None:
    """``(peak, first)``: the path's first unloading step and the step before it, when
    both converged and U moves between them by more than ``SLOPE_RESOLUTION`` times its
    accuracy (the worst KKT residual of the two, at least machine epsilon, times the
    displacement scale max(|U|, max|u|) of the peak); else None (also when the path never
    unloads). Measured: unloading 3000 to 2999.9999999 moves U by 3e-11 of itself, and
    the secant's slope was 2.07e5 by newton, 3.08e5 by conic."""
    first = next((s for s in result.steps if s.unloading), None)
    if first is None:
        return None
    peak = result.steps[first.index - 2]
    if not (peak.converged and first.converged):
        return None
    scale = max(abs(peak.U), float(np.abs(peak.u).max(initial=0.0)))
    accuracy = max(peak.solution.kkt.worst, first.solution.kkt.worst, float(np.finfo(float).eps)) * scale
    return (peak, first) if abs(peak.U - first.U) > SLOPE_RESOLUTION * accuracy else None


def unloading_slope(result: PathResult) -> dict[str, Any] | None:
    """The initial elastic unloading slope: the secant ``S = (F_peak - F_1) /
    (U_peak - U_1)`` of the path's first unloading step, from the peak before it; None
    when the path never unloads, or when that step did not converge or moved U by no
    more than its accuracy resolves (:func:`first_unloading_step`)."""
    span = first_unloading_step(result)
    if span is None:
        return None
    peak, first = span
    dU = peak.U - first.U
    return {"S": (peak.force - first.force) / dU, "step": first.index, "F_peak": peak.force, "U_peak": peak.U,
            "F": first.force, "U": first.U, "reverse_yield": first.reverse_yield}


def residual_imprint(result: PathResult) -> dict[str, Any] | None:
    """The residual imprint: U at the end of the last unloading (the last unbroken run of
    steps whose force falls), the depth the rigid body's imprint keeps as the force goes
    to 0+ (a path ends its unloading at a small force > 0: at F = 0, U is not determined);
    the value of :meth:`PathResult.residual_imprint`, with the step, its force and the
    peak the run started from. None when the path never unloads."""
    runs: list[list[PathStep]] = []
    for i, step in enumerate(result.steps):
        if step.unloading:
            if i > 0 and result.steps[i - 1].unloading:
                runs[-1].append(step)
            else:
                runs.append([step])
    if not runs:
        return None
    end, peak = runs[-1][-1], result.steps[runs[-1][0].index - 2]
    return {"U": end.U, "force": end.force, "step": end.index, "F_peak": peak.force, "U_peak": peak.U,
            "converged": end.converged}


def path_oliver_pharr(disc: Discretization, result: PathResult) -> dict[str, Any] | None:
    """The Oliver-Pharr figures of the path's first unloading
    (:func:`~elastoplast.certificate.oliver_pharr.oliver_pharr`) from the converged steps'
    (U, F), F the whole indenter force (the model's over its symmetry share,
    ``force_share``); None when
    the path never unloads (or its first unloading step is not resolved:
    :func:`first_unloading_step`), in plane strain (no projected area), or for an obstacle
    other than a sphere, paraboloid or cone."""
    obstacle = disc.problem.obstacle
    axisymmetric = disc.problem.axisymmetric
    if (disc.dim == 2 and not axisymmetric) or obstacle.shape not in SHAPES:
        return None
    if first_unloading_step(result) is None:  # never unloads, or by less than U resolves
        return None
    steps = [s for s in result.steps if s.converged]
    share = 1.0 if axisymmetric else symmetry_share(disc)
    m = disc.material
    out = oliver_pharr([0.0] + [s.U for s in steps], [0.0] + [s.force / share for s in steps], shape=obstacle.shape,
                       E=m.E, nu=m.nu, radius=obstacle.radius, half_angle=obstacle.half_angle)
    return None if out is None else {**out, "force_share": share}


def yielded(step: PathStep, disc: Discretization, tol: float) -> np.ndarray:
    """The elements that yield in ``step``: ``dkappa`` above the round-off threshold
    of :func:`~elastoplast.solvers.path.solve_path` (``tol`` times the yield strain)."""
    m = disc.material
    return step.dkappa > YIELD_STRAIN_SHARE * tol * m.yield_stress / m.E


def step_entry(disc: Discretization, step: PathStep) -> dict[str, Any]:
    """A step's entry of ``summary.json``'s ``"path"``: :meth:`PathStep.summary` and
    the contact radius (half-width in 2D), the number of active contact nodes (the relative
    threshold of a plain solve's summary, ``ACTIVE_FORCE_SHARE``) and largest contact
    pressure after the step."""
    sol = step.solution
    finite = sol.contact_pressure[np.isfinite(sol.contact_pressure)]
    return {**step.summary(disc), "contact_radius": contact_radius(disc, sol.active, sol.contact_pressure),
            "n_active_contact_nodes": int(np.sum(sol.active)),
            "max_contact_pressure": float(finite.max()) if finite.size else float("nan")}


def path_summary(disc: Discretization, result: PathResult) -> dict[str, Any]:
    """Everything ``summary.json`` holds for a path but the provenance: the keys of a
    Hencky solve's summary for the path's answer (:func:`path_solution`: the state after
    the last step, its certificate the last step's), then the path's own, which win
    where both have one: its status and message, its forces (``force`` the largest),
    the last step's U, the worst KKT residual over the steps, the iterations and time
    of all steps, the residual imprint and the unloading slope, the Oliver-Pharr figures
    (:func:`path_oliver_pharr`) and the indentation figures after the last step (at its force), and ``"path"``, one
    entry per step in order (:func:`step_entry`). A depth path (``control`` =
    ``"displacement"``) lists its prescribed ``displacements`` and, as ``forces``, the
    forces found at its steps."""
    status, message = path_status(result)
    entries = [step_entry(disc, s) for s in result.steps]
    depth = result.control == "displacement"  # a depth path: the loads are displacements, the forces found
    forces = [float(s.force) for s in result.steps] if depth else list(result.forces)
    control = {"control": result.control}
    if depth:
        control["displacements"] = list(result.forces)
    return {
        **summary(disc, path_solution(result)), **control,
        "method": result.method, "status": status.value, "message": message,
        "forces": forces, "force": max(forces, default=float("nan")), "n_steps": len(result.forces),
        "n_steps_run": len(result.steps), "n_converged": sum(s.converged for s in result.steps),
        "U": float(result.steps[-1].U) if result.steps else float("nan"),
        "kkt_worst": max((e["kkt_worst"] for e in entries), default=float("nan")),
        "iterations": sum(e["iterations"] for e in entries), "time_s": float(result.time_s),
        "residual_imprint": residual_imprint(result), "unloading_slope": unloading_slope(result),
        "oliver_pharr": path_oliver_pharr(disc, result),
        "indentation": (indentation_summary(disc, path_solution(result), axisymmetric=disc.problem.axisymmetric,
                                            force=result.steps[-1].force) if result.steps else None),
        "n_elements": disc.n_elements, "n_nodes": disc.mesh.n_nodes, "dim": disc.dim,
        "path": entries,
    }


def write_step_vtu(path: str | Path, disc: Discretization, step: PathStep, tol: float) -> None:
    """One step as ``solution.vtu`` is written (:func:`~elastoplast.io.output.write_vtu`),
    with the total displacement as ``displacement`` and, per element, ``kappa`` (the
    accumulated equivalent plastic strain), ``dkappa`` (its increment in the step),
    ``yielded`` (1 where the element yields in the step) and ``plastic_ever``
    (1 where kappa > 0); ``plastic`` is as for Hencky: on the yield surface now."""
    write_vtu(path, disc, replace(step.solution, u=step.u),
              cell_data={"kappa": step.kappa, "dkappa": step.dkappa,
                         "yielded": yielded(step, disc, tol).astype(np.int32),
                         "plastic_ever": (step.kappa > 0.0).astype(np.int32)})


def pvd_text(files: list[str], times: list[float]) -> str:
    """A ParaView collection (``.pvd``) playing ``files`` at ``times``."""
    rows = "".join(f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>\n'
                   for f, t in zip(files, times))
    return ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
            f"  <Collection>\n{rows}  </Collection>\n</VTKFile>\n")


def write_path_files(folder: str | Path, disc: Discretization, result: PathResult, tol: float) -> list[str]:
    """Write ``solution_NNN.vtu`` for every step run and ``path.pvd`` listing them
    (the step's number as its time) into ``folder``; returns the vtu names in order."""
    folder = Path(folder)
    names = []
    for step in result.steps:
        name = step_file_name(step.index, len(result.forces))
        write_step_vtu(folder / name, disc, step, tol)
        names.append(name)
    (folder / PVD_NAME).write_text(pvd_text(names, [float(s.index) for s in result.steps]))
    return names
