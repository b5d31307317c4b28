"""``elastoplast solve`` on a problem with a loading path (``[load] path = [...]``):
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
from elastoplast.solvers.path import PathStep, solve_path
from elastoplast.studies.loading_path import write_path_results


def has_path(data: Any) -> bool:
    """Whether a problem file's table gives a loading path (``[load] path``)."""
    load = data.get("load") if isinstance(data, Mapping) else None
    return isinstance(load, Mapping) and "path" in load


def refuse_path(data: Any, command: str) -> None:
    """The commands that take Hencky's problem (``bounds``, ``adapt``, ``check``,
    ``export``) refuse a loading path, naming ``load.path``, before any work."""
    if has_path(data):
        raise InputError("load.path", f"'{command}' takes Hencky's problem (load.force); a loading path is solved "
                                      "by 'solve' (and campaigns and compare): write force = F for this command")


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
    forces = disc.problem.path
    quiet = args.quiet
    if not quiet:
        print(problem_line(path, disc, f"loading path of {len(forces)} steps by {method}"), file=sys.stderr)

    def show(step: PathStep) -> None:
        if not quiet:
            print(step_line(step, len(forces)), file=sys.stderr, flush=True)

    # the steps' own progress bars would bury the step lines: one line per step instead
    result = solve_path(disc, forces, method, options=replace(opts, progress=False), callback=show)
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
