"""``elastoplast solve`` on a problem with a loading path (``[load] path = [...]``, or a
depth path ``displacement_path``) or under depth control (``[load] displacement``):
every step solved by the chosen method (:func:`~elastoplast.solvers.path.solve_path`),
one line per step on stderr, and the path's files written together into ``--out``
(:func:`~elastoplast.studies.loading_path.write_path_results`); and the refusal of the
commands that take Hencky's problem only.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from elastoplast.cli.exits import outcome
from elastoplast.cli.printing import discretize_file, problem_line
from elastoplast.errors import InputError, figure
from elastoplast.options import SolverOptions
from elastoplast.solvers.depth import solve_depth, solve_depth_path
from elastoplast.solvers.path import PathStep, solve_path
from elastoplast.studies.loading_path import write_path_results


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
    from elastoplast.io.output import json_text, staged_output
    from elastoplast.io.provenance import stamp
    from elastoplast.studies.results import write_results

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
