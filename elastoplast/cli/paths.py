"""``elastoplast solve`` on a problem with a loading path (``[load] path = [...]``):
every step solved by the chosen method (:func:`~elastoplast.solvers.path.solve_path`),
one line per step on stderr, and the path's files written together into ``--out``:
``summary.json`` (with ``"path"``, one entry per step), ``solution_NNN.vtu`` per step,
``path.pvd`` to play them in ParaView, and ``path.png``, the load-displacement loop with
the residual imprint and the initial unloading slope. Also a path case of a campaign
(:func:`path_case`) and the refusal of the commands that take Hencky's problem only.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from elastoplast.cli.exits import outcome
from elastoplast.cli.printing import discretize_file, figure, problem_line
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization
from elastoplast.io.paths import path_solution, path_summary, write_path_files
from elastoplast.options import SolverOptions
from elastoplast.solvers.depth import solve_depth, solve_depth_path
from elastoplast.solvers.path import PathResult, PathStep, solve_path


def load_keys(data: Any) -> set[str]:
    """The keys of a problem file's ``[load]`` table (empty when it has none)."""
    load = data.get("load") if isinstance(data, Mapping) else None
    return set(load) if isinstance(load, Mapping) else set()


def has_path(data: Any) -> bool:
    """Whether a problem file's table gives a loading path (``[load] path``, or a
    depth path ``displacement_path``)."""
    return bool(load_keys(data) & {"path", "displacement_path"})


def has_depth(data: Any) -> bool:
    """Whether a problem file prescribes the indenter's displacement (``[load] displacement``)."""
    return "displacement" in load_keys(data)


def refuse_path(data: Any, command: str) -> None:
    """The commands that take Hencky's problem under a force (``bounds``, ``adapt``,
    ``check``, ``export``) refuse a loading path and depth control, naming the key,
    before any work."""
    for key in ("path", "displacement_path", "displacement"):
        if key in load_keys(data):
            raise InputError(f"load.{key}", f"'{command}' takes Hencky's problem under a force (load.force); "
                                            f"load.{key} is solved by 'solve': write force = F for this command")


def step_line(step: PathStep, n_steps: int) -> str:
    """The progress line of one step."""
    sol = step.solution
    turn = " (unloading)" if step.unloading else ""
    reverse = f", {step.reverse_yield} reverse-yielding" if step.reverse_yield else ""
    return (f"[{step.index}/{n_steps}] F = {step.force:.6g}{turn}: {sol.status.value}, U = {figure(step.U, '.6g')}, "
            f"KKT {figure(sol.kkt.worst, '.1e')}, {step.yielding} yielding{reverse}, {sol.iterations} iterations, "
            f"{sol.time_s:.2f} s")


def plot_path(path: str | Path, record: Mapping[str, Any], title: str = "") -> None:
    """``path.png``: F against U through the steps (the loop), each step a marker,
    unloading steps hollow; the residual imprint U_res of the first unloading marked on
    the U axis, and the initial unloading slope S drawn from the peak down to F = 0."""
    from matplotlib.figure import Figure

    steps = record["path"]
    U = [0.0] + [s["U"] for s in steps]
    F = [0.0] + [s["force"] for s in steps]
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(U, F, "-", color="0.3", lw=1.2, label="path (backward Euler steps)")
    load = [s for s in steps if not s["unloading"]]
    unload = [s for s in steps if s["unloading"]]
    ax.plot([s["U"] for s in load], [s["force"] for s in load], "o", color="C0", ms=4, label="loading step")
    ax.plot([s["U"] for s in unload], [s["force"] for s in unload], "o", mfc="none", color="C1", ms=5,
            label="unloading step")
    bad = [s for s in steps if s["status"] != "converged"]
    if bad:
        ax.plot([s["U"] for s in bad], [s["force"] for s in bad], "x", color="red", ms=9, label="not converged")
    slope = record.get("unloading_slope")
    if slope:
        u0 = slope["U_peak"] - slope["F_peak"] / slope["S"]
        ax.plot([slope["U_peak"], u0], [slope["F_peak"], 0.0], "--", color="C2", lw=1.2,
                label=f"initial unloading slope S = {slope['S']:.4g}")
    imprint = record.get("residual_imprint")
    if imprint:
        ax.axvline(imprint["U"], color="C3", lw=0.8, ls=":")
        ax.plot([imprint["U"]], [imprint["force"]], "s", color="C3", ms=6,
                label=f"residual imprint U_res = {imprint['U']:.4g} (F = {imprint['force']:.3g})")
    ax.set_xlabel("U (rigid body's displacement)")
    ax.set_ylabel("F")
    ax.set_xlim(left=min(0.0, *U))
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(title, fontsize=10)
    fig.savefig(path, dpi=120)


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


def solve_path_command(args: argparse.Namespace, path: Path, data: dict, method: str, opts: SolverOptions) -> int:
    """``elastoplast solve`` on a path problem; the exit code is 0 only when every
    step converged."""
    disc = discretize_file(path, data)
    depths = disc.problem.displacement_path
    forces = disc.problem.path if depths is None else depths
    quiet = args.quiet
    if not quiet:
        kind = "loading path" if depths is None else "depth path"
        print(problem_line(path, disc, f"{kind} of {len(forces)} steps by {method}"), file=sys.stderr)

    def show(step: PathStep) -> None:
        if not quiet:
            print(step_line(step, len(forces)), file=sys.stderr, flush=True)

    # the steps' own progress bars would bury the step lines: one line per step instead
    if depths is None:
        result = solve_path(disc, forces, method, options=replace(opts, progress=False), callback=show)
    else:
        result, _ = solve_depth_path(disc, depths, method, options=replace(opts, progress=False), callback=show)
    record = write_path_results(args.out, disc, result, opts.tol, field="--out")
    imprint, slope = record["residual_imprint"], record["unloading_slope"]
    extra = ""
    if imprint:
        extra += f", residual imprint U_res = {figure(imprint['U'], '.6g')} at F = {imprint['force']:.4g}"
    if slope:
        extra += f", initial unloading slope S = {figure(slope['S'], '.6g')}"
    print(f"{record['status']}: {record['message']}; U = {figure(record['U'], '.6g')} at the last step{extra}")
    print(f"KKT worst residual over the steps {figure(record['kkt_worst'], '.2e')}, {record['iterations']} "
          f"iterations, {result.time_s:.2f} s -> {Path(args.out) / 'summary.json'}")
    return outcome(result.converged, f"not converged: {record['message']}")


def solve_depth_command(args: argparse.Namespace, path: Path, data: dict, method: str, opts: SolverOptions) -> int:
    """``elastoplast solve`` under depth control (``[load] displacement``): the force
    found, the files of a Hencky solve at that force, and in ``summary.json`` the depth
    control's own keys (:meth:`~elastoplast.solvers.depth.DepthSolution.summary`). At
    lift-off no solve is made: ``summary.json`` alone, F = 0."""
    from elastoplast.cli.results import write_results
    from elastoplast.io.output import json_text, staged_output
    from elastoplast.io.provenance import stamp

    disc = discretize_file(path, data)
    delta = disc.problem.displacement
    if not args.quiet:
        print(problem_line(path, disc, f"depth control U = {delta:g} by {method}"), file=sys.stderr)
    out = solve_depth(disc, delta, method, options=replace(opts, progress=False))
    extra = out.summary()
    if out.solution is None:
        with staged_output(args.out, "--out") as tmp:
            (tmp / "summary.json").write_text(json_text({**extra, "method": method, "provenance": stamp()}))
        print(f"lift-off: U = {figure(delta, '.6g')} is at or above the unloaded gap {figure(delta - out.depth, '.6g')}: "
              f"no contact, F = 0 -> {Path(args.out) / 'summary.json'}")
        return outcome(True, "")
    sol = out.solution
    write_results(args.out, disc.with_force(out.force), sol, extra, field="--out")
    print(f"{sol.status.value}: F = {figure(out.force, '.6g')} at U = {figure(sol.U, '.6g')} (prescribed "
          f"{figure(delta, '.6g')}, |U - delta| / depth {figure(out.residual, '.1e')}), {len(out.forces)} solves")
    print(f"KKT worst residual {figure(sol.kkt.worst, '.2e')}, duality gap {figure(sol.duality_gap, '.2e')} "
          f"-> {Path(args.out) / 'summary.json'}")
    return outcome(sol.converged, f"not converged: {sol.message}")


def path_case(problem, spec: Mapping[str, Any]) -> dict[str, Any]:
    """A campaign case with a loading path (or a depth path): the path solved by the case's method, its
    answer as one solution (:func:`~elastoplast.io.paths.path_solution`: the last step,
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
    with its ``summary.json`` (the depth keys of :func:`solve_depth_command` added) and
    VTU. A lift-off has no solution to store: an :class:`InputError` saying F = 0."""
    from elastoplast.cli.results import write_files
    from elastoplast.fem.discretize import discretize
    from elastoplast.solvers.registry import method_options

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
