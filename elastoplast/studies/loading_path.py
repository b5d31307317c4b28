"""The files of a loading path, written together: ``summary.json`` (with ``"path"``,
one entry per step), ``solution_NNN.vtu`` per step, ``path.pvd`` to play them in
ParaView, and ``path.png``, the load-displacement loop with the residual imprint and
the initial unloading slope (:func:`write_path_results`); and a path case of a campaign
(:func:`path_case`) or a depth-controlled one (:func:`depth_case`)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Mapping

from elastoplast.fem.discretize import Discretization
from elastoplast.io.loading_path import path_solution, path_summary, write_path_files
from elastoplast.plots.figures import plot_path
from elastoplast.errors import InputError
from elastoplast.solvers.depth import solve_depth, solve_depth_path
from elastoplast.solvers.path import PathResult, solve_path


def write_path_results(out_dir: str | Path, disc: Discretization, result: PathResult, tol: float, *,
                       field: str = "out") -> dict[str, Any]:
    """Write the path's files into ``out_dir`` (staged: the folder is replaced only
    when every file is written) and return the summary."""
    from elastoplast.io.output import json_text, staged_output
    from elastoplast.io.provenance import stamp

    record = path_summary(disc, result)
    with staged_output(out_dir, field) as tmp:
        record["files"] = write_path_files(tmp, disc, result, tol)
        record["provenance"] = stamp()
        (tmp / "summary.json").write_text(json_text(record))
        plot_path(tmp / "path.png", record, f"{result.method}: {record['message']}")
    return record


def path_case(problem, spec: Mapping[str, Any]) -> dict[str, Any]:
    """A campaign case with a loading path (or a depth path): the path solved by the case's method, its
    answer as one solution (:func:`~elastoplast.io.loading_path.path_solution`: the last step,
    total displacement, the path's status), ``summary.json`` with the path's summary
    (``"path"``: every step) and the last step's VTU."""
    from elastoplast.fem.discretize import discretize
    from elastoplast.io.output import write_vtu
    from elastoplast.io.provenance import stamp
    from elastoplast.solvers.registry import method_options

    disc = discretize(problem)
    opts = method_options(spec["method"], spec["options"])
    if problem.displacement_path is not None:
        result, _ = solve_depth_path(disc, problem.displacement_path, spec["method"], options=opts)
    else:
        result = solve_path(disc, problem.path, spec["method"], options=opts)
    sol = path_solution(result)
    record = {**path_summary(disc, result), "provenance": stamp()}
    with tempfile.TemporaryDirectory(prefix="elastoplast-case-") as tmp:
        write_vtu(Path(tmp) / "solution.vtu", disc, sol)
        vtu = (Path(tmp) / "solution.vtu").read_bytes()
    return {"solution": sol, "summary": record, "vtu": vtu}


def depth_case(problem, spec: Mapping[str, Any]) -> dict[str, Any]:
    """A campaign case under depth control: the force found, the Hencky solve at it
    with its ``summary.json`` (the depth keys of
    :func:`~elastoplast.solvers.depth.DepthSolution.summary` added) and VTU. A lift-off
    has no solution to store: an :class:`InputError` saying F = 0."""
    from elastoplast.fem.discretize import discretize
    from elastoplast.solvers.registry import method_options
    from elastoplast.studies.results import write_files

    disc = discretize(problem)
    out = solve_depth(disc, problem.displacement, spec["method"],
                      options=method_options(spec["method"], spec["options"]))
    if out.solution is None:
        raise InputError("load.displacement", f"{problem.displacement:g} is at or above the unloaded gap: lift-off, "
                                              "F = 0 and no contact (no solution to store)")
    with tempfile.TemporaryDirectory(prefix="elastoplast-case-") as tmp:
        data = write_files(Path(tmp), disc.with_force(out.force), out.solution, out.summary())
        vtu = (Path(tmp) / "solution.vtu").read_bytes()
    return {"solution": out.solution, "summary": data, "vtu": vtu}
