"""Adaptive refinement driven by the certified gap (issue 11).

The gap between the upper bound Π(v, V) of the P1 solution and the lower bound
−J of the equilibrium element (docs/bounds.md) is a sum of element and
contact-facet terms, each ≥ 0: a proof in total and an error indicator in its
parts. The loop

    solve (2.1) → bound (lower, upper, local gaps) → mark (Dörfler, θ) → refine

runs until the relative gap ``(upper − lower) / |upper|`` is at most ``rtol``, or
the next mesh would exceed ``max_elements``, or ``time_limit`` has passed, or
``max_steps`` meshes were solved. Marking uses the element gaps, each contact
facet's gap added to the element it bounds (:func:`element_indicators`);
refinement is conforming newest-vertex bisection
(:func:`~elastoplast.refinement.refine`), which keeps the facet groups, so the
contact zone and the symmetry planes stay exact and every mesh is nested in
the last. For comparison, :func:`uniform` runs the same pipeline refining every
element.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from .discretize import Discretization, discretize
from .errors import InputError
from .mesh import Mesh
from .options import SolverOptions, option
from .problem import Problem
from .bounds import element_indicators
from .refinement import dorfler_mark, refine
from .solution import Solution


@dataclass(frozen=True)
class AdaptOptions(SolverOptions):
    """Settings of :func:`adapt` (declared and checked like every solver's options).

    ``tol`` here is ``rtol``'s companion for the P1 solves: the KKT tolerance
    each mesh's discrete solution is certified to (the bounds need the discrete
    solution only as a candidate, but an accurate one keeps the upper bound
    tight). ``max_iter`` bounds the number of meshes (``max_steps``).
    """

    max_iter: int = option(30, int, "most meshes solved (adaptive steps)", lo=1, hi=200)
    tol: float = option(1e-8, float, "KKT tolerance of each mesh's P1 solution", lo=1e-13, hi=1e-4)
    rtol: float = option(1e-3, float, "target relative energy gap (upper - lower) / |upper|", lo=1e-8, hi=1.0,
                         lo_open=True)
    theta: float = option(0.5, float, "Dörfler parameter: mark the smallest set carrying this share of the gap",
                          lo=0.0, hi=1.0, lo_open=True)
    max_elements: int = option(2_000_000, int, "stop before a mesh with more elements", lo=1, hi=100_000_000)
    method: str = option("newton", str, "the P1 solver", choices=("conic", "newton", "uzawa", "uzawa-fast"))
    bracket: str = option("every", str, "U bracket at every step, the final one only, or never",
                          choices=("every", "final", "never"))
    compare_uniform: bool = option(True, bool, "also run uniform refinement for the plot")


@dataclass(frozen=True)
class Step:
    """One mesh of the sequence: its size, bounds, U bracket and cost."""

    step: int
    n_elements: int
    n_nodes: int
    energy_lower: float
    energy_upper: float
    gap_rel: float
    certified: bool
    U: float
    U_lower: float
    U_upper: float
    seconds: float
    marked: int = 0

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def line(self) -> str:
        bracket = "" if math.isnan(self.U_lower) else f"  U in [{self.U_lower:.6g}, {self.U_upper:.6g}]"
        flag = "" if self.certified else "  (NOT certified)"
        return (f"step {self.step:2d}  {self.n_elements:9,d} elements  lower {self.energy_lower:.8g}  "
                f"upper {self.energy_upper:.8g}  gap {self.gap_rel:.3e}{bracket}  {self.seconds:.1f} s{flag}")


@dataclass(frozen=True)
class AdaptResult:
    """The sequence of meshes and the final answer: ``disc``, ``solution``,
    ``bounds`` (:class:`~elastoplast.bounds.Bounds`) of the last mesh;
    ``meshes`` every mesh solved; ``reason`` why the loop stopped."""

    steps: tuple[Step, ...]
    meshes: tuple[Mesh, ...] = field(repr=False)
    disc: Discretization = field(repr=False)
    solution: Solution = field(repr=False)
    bounds: Any = field(repr=False)
    reason: str = ""

    @property
    def final(self) -> Step:
        return self.steps[-1]


def bound_mesh(problem: Problem, options: AdaptOptions, *, bracket: bool, step: int = 0,
               t_start: float | None = None) -> tuple[Step, Discretization, Solution, Any]:
    """Solve and bound one mesh: the :class:`Step` row and what it was computed from."""
    from .bounds import bounds_at, choose_delta, displacement_slope, energy_bounds, u_bracket
    from .solvers import solve

    t0 = time.perf_counter() if t_start is None else t_start
    disc = discretize(problem)
    solver = {"tol": options.tol} if options.method != "conic" else {}
    sol = solve(disc, options.method, **solver)
    if not sol.converged:
        raise InputError("adapt", f"the P1 solution on mesh {step} ({disc.n_elements} elements) did not "
                                  f"converge: {sol.message}")
    b = energy_bounds(disc, solution=sol, method=options.method, **solver)
    U_lo = U_hi = math.nan
    if bracket:
        gap = b.energy_upper - b.energy_lower
        delta = choose_delta(disc.force, gap, displacement_slope(disc, options.method, **solver))
        U_lo, U_hi = u_bracket(disc, delta, bounds_at(disc, method=options.method, **solver))
    row = Step(step=step, n_elements=disc.n_elements, n_nodes=disc.mesh.n_nodes, energy_lower=b.energy_lower,
               energy_upper=b.energy_upper, gap_rel=b.energy_gap_rel, certified=b.bounds_certified, U=sol.U,
               U_lower=U_lo, U_upper=U_hi, seconds=time.perf_counter() - t0)
    return row, disc, sol, b


def adapt(problem: Problem, options: AdaptOptions = AdaptOptions(),
          report: Callable[[Step], None] | None = None) -> AdaptResult:
    """Refine where the certified gap is, until ``rtol`` or a budget; see the module docstring.

    ``report`` is called with each :class:`Step` as it is done (the command
    line prints it).
    """
    return _loop(problem, options, report, mark=lambda eta: dorfler_mark(eta, options.theta))


def uniform(problem: Problem, options: AdaptOptions = AdaptOptions(), max_elements: int | None = None,
            report: Callable[[Step], None] | None = None) -> AdaptResult:
    """The same pipeline refining every element (the comparison of the issue),
    up to ``max_elements`` (default: the options')."""
    opts = replace(options, max_elements=max_elements or options.max_elements, bracket="never", rtol=options.rtol)
    return _loop(problem, opts, report, mark=lambda eta: np.ones(eta.size, dtype=bool))


def _loop(problem: Problem, options: AdaptOptions, report, mark) -> AdaptResult:
    t_start = time.perf_counter()
    mesh, state = problem.mesh, None
    steps: list[Step] = []
    meshes: list[Mesh] = []
    growth = 2 ** problem.dim  # a refinement step at most multiplies the elements by about this
    reason = f"max_iter = {options.max_iter} meshes solved"
    for k in range(options.max_iter):
        t0 = time.perf_counter()
        last = k == options.max_iter - 1
        row, disc, sol, b = bound_mesh(replace(problem, mesh=mesh), options, step=k, t_start=t0,
                                       bracket=options.bracket == "every")
        meshes.append(mesh)
        done = None
        elapsed = time.perf_counter() - t_start
        if row.gap_rel <= options.rtol:
            done = f"relative gap {row.gap_rel:.3e} <= rtol {options.rtol:g}"
        elif options.time_limit is not None and elapsed >= options.time_limit:
            done = f"time_limit {options.time_limit:g} s reached"
        eta = element_indicators(disc, b)
        marked = mark(eta)
        if done is None and not last:
            new_mesh, new_state, _ = refine(mesh, marked, state)
            if new_mesh.n_elements > options.max_elements:
                done = f"the next mesh would have {new_mesh.n_elements:,} elements > max_elements {options.max_elements:,}"
        if done is not None or last:
            if options.bracket == "final" and math.isnan(row.U_lower):
                row, disc, sol, b = bound_mesh(replace(problem, mesh=mesh), options, step=k, t_start=t0, bracket=True)
            steps.append(row)
            if report is not None:
                report(row)
            reason = done or reason
            break
        row = replace(row, marked=int(marked.sum()), seconds=time.perf_counter() - t0)
        steps.append(row)
        if report is not None:
            report(row)
        mesh, state = new_mesh, new_state
    return AdaptResult(steps=tuple(steps), meshes=tuple(meshes), disc=disc, solution=sol, bounds=b, reason=reason)


def fitted_rate(steps: tuple[Step, ...] | list[Step]) -> float:
    """The exponent p of ``gap_rel ~ elements^(-p)``, least squares over the steps
    (NaN with fewer than two)."""
    n = np.array([s.n_elements for s in steps], dtype=float)
    g = np.array([s.gap_rel for s in steps], dtype=float)
    ok = (n > 0) & (g > 0) & np.isfinite(g)
    if ok.sum() < 2:
        return math.nan
    return float(-np.polyfit(np.log(n[ok]), np.log(g[ok]), 1)[0])


__all__ = ["AdaptOptions", "AdaptResult", "Step", "adapt", "bound_mesh", "fitted_rate", "run_adapt_command",
           "uniform"]


# ----------------------------------------------------------------------------
# the command: run, compare with uniform refinement, write everything
# ----------------------------------------------------------------------------


def write_table(path, adaptive: AdaptResult, uniform_run: AdaptResult | None) -> str:
    """The steps as a Markdown table (adaptive, then uniform), with the fitted rates."""
    head = "| run | step | elements | lower | upper | relative gap | U lower | U upper | s | certified |"
    lines = [head, "|" + "---|" * 10]
    for name, run in (("adaptive", adaptive), ("uniform", uniform_run)):
        if run is None:
            continue
        for s in run.steps:
            lines.append(f"| {name} | {s.step} | {s.n_elements} | {s.energy_lower:.10g} | {s.energy_upper:.10g} | "
                         f"{s.gap_rel:.3e} | {s.U_lower:.6g} | {s.U_upper:.6g} | {s.seconds:.1f} | "
                         f"{'yes' if s.certified else 'no'} |")
    lines += ["", f"Stopped: {adaptive.reason}.", "",
              f"Fitted rate of the relative gap in the number of elements (gap ~ N^-p): adaptive p = "
              f"{fitted_rate(adaptive.steps):.3f}"
              + ("" if uniform_run is None else f", uniform p = {fitted_rate(uniform_run.steps):.3f}") + "."]
    text = "\n".join(lines) + "\n"
    from pathlib import Path

    Path(path).write_text(text)
    return text


def plot_gaps(path, adaptive: AdaptResult, uniform_run: AdaptResult | None, title: str = "") -> None:
    """The relative gap against the number of elements, adaptive and uniform (log-log)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    for name, run, style in (("adaptive", adaptive, "o-"), ("uniform", uniform_run, "s--")):
        if run is None:
            continue
        n = [s.n_elements for s in run.steps]
        g = [s.gap_rel for s in run.steps]
        ax.loglog(n, g, style, label=f"{name} (p = {fitted_rate(run.steps):.2f})")
    ax.set_xlabel("elements")
    ax.set_ylabel("relative energy gap (upper − lower) / |upper|")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.savefig(path, dpi=120)


def run_adapt_command(problem: Problem, options: AdaptOptions, out_dir) -> bool:
    """``elastoplast adapt``: the adaptive run (one line per step on stdout, a
    progress bar on stderr), the uniform comparison up to the adaptive run's
    final size, and the files: ``adapt.md``/``adapt.json`` (the table),
    ``gap.png``, ``meshes/mesh_NNN.msh`` (every adapted mesh, gmsh format with the
    facet groups), and ``solution.vtu``/``summary.json`` of the final mesh with its
    bounds and local gaps. Returns whether the final bounds are certified and
    reach ``rtol``."""
    import sys

    from tqdm.auto import tqdm

    from .bounds import gap_fields
    from .mesh import write_mesh
    from .output import json_text, staged_output, write_files
    from .provenance import stamp

    with staged_output(out_dir, "--out") as tmp:
        bar = tqdm(total=options.max_iter, desc="adapt", unit="mesh", disable=not options.progress, file=sys.stderr,
                   leave=False)

        def report(step: Step) -> None:
            bar.update(1)
            bar.set_postfix(gap=f"{step.gap_rel:.2e}", elements=step.n_elements)
            tqdm.write(step.line(), file=sys.stdout)

        run = adapt(problem, options, report=report)
        bar.close()
        uni = None
        if options.compare_uniform:
            print("uniform refinement, for comparison:", file=sys.stdout)
            uni = uniform(problem, options, max_elements=max(run.final.n_elements, problem.mesh.n_elements) * 2 ** problem.dim,
                          report=lambda s: tqdm.write(s.line(), file=sys.stdout))
        (tmp / "meshes").mkdir()
        for k, mesh in enumerate(run.meshes):
            write_mesh(tmp / "meshes" / f"mesh_{k:03d}.msh", mesh)
        write_table(tmp / "adapt.md", run, uni)
        (tmp / "adapt.json").write_text(json_text({
            "reason": run.reason, "options": options.persistent(),
            "adaptive": [s.as_dict() for s in run.steps], "adaptive_rate": fitted_rate(run.steps),
            "uniform": None if uni is None else [s.as_dict() for s in uni.steps],
            "uniform_rate": None if uni is None else fitted_rate(uni.steps), "provenance": stamp()}))
        plot_gaps(tmp / "gap.png", run, uni, title=f"certified gap, {problem.dim}D")
        b = run.bounds
        final = run.final
        write_files(tmp, run.disc, run.solution,
                    extra={**b.as_dict(), "U_lower": final.U_lower, "U_upper": final.U_upper,
                           "adapt_steps": len(run.steps), "adapt_reason": run.reason},
                    **gap_fields(run.disc, b))
    print(f"{run.reason}: {final.n_elements:,} elements, relative gap {final.gap_rel:.3e}"
          + ("" if math.isnan(final.U_lower) else f", U in [{final.U_lower:.6g}, {final.U_upper:.6g}]")
          + f" -> {out_dir}")
    return bool(final.certified and final.gap_rel <= options.rtol)
