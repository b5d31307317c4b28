"""Command line: ``elastoplast solve [PROBLEM.toml] --method M --out DIR``,
``elastoplast campaign CAMPAIGN.toml --out DIR [--scheduler ADDRESS]`` and
``elastoplast compare DIR --method M``.

Exit codes: 0 solved and certified, 1 the solver did not converge (the status
says why; files are still written), 2 bad input (one line naming the field),
3 an internal error (a bug: one line; ``ELASTOPLAST_DEBUG=1`` shows the
traceback), 130 interrupted.

Every solver option reaches the method through one path
(:func:`elastoplast.solvers.method_options`): ``--tol``, ``--max-iter``,
``--rho`` and ``--time-limit`` are shorthands for ``--option NAME=VALUE``, which
sets any option of the chosen method; the file's ``[solver]`` table comes
first and the command line wins.
"""

from __future__ import annotations

import argparse
import os
import sys
import tomllib
import warnings
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

from .errors import InputError

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

#: command-line shorthands for solver options: flag -> option name
OPTION_FLAGS = {"--tol": "tol", "--max-iter": "max_iter", "--rho": "rho", "--time-limit": "time_limit"}


def default_problem_path() -> Path:
    """The built-in default problem shipped with the package."""
    return Path(str(resources.files("elastoplast") / "data" / "default.toml"))


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # usage errors are input errors: exit 2, one line
        self.print_usage(sys.stderr)
        raise InputError("arguments", message)


def build_parser() -> argparse.ArgumentParser:
    from .solvers import METHODS

    parser = _Parser(prog="elastoplast", description="Reference solutions of an elasto-plastic contact problem.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("solve", help="solve one problem and write solution.vtu and summary.json")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--method", help=f"solver, one of {sorted(METHODS)} (default: the file's [solver] method, else conic)")
    p.add_argument("--out", default="results", help="output folder, new or holding an earlier output (default: results)")
    _add_solver_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("campaign", help="run a sweep of problems on Dask into a resumable store of reference solutions")
    p.add_argument("campaign", help="campaign TOML file: a base problem and [sweep] axes")
    p.add_argument("--out", required=True, help="store directory (created; re-running skips the cases it holds)")
    _add_dask_arguments(p)
    p.add_argument("--retry-failed", action="store_true", help="also re-run stored cases the solver did not solve")

    p = sub.add_parser("compare", help="run a method on every stored reference case and report its errors")
    p.add_argument("store", help="store directory written by 'elastoplast campaign'")
    p.add_argument("--method", required=True, help=f"method to compare (one of {sorted(METHODS)})")
    _add_solver_arguments(p)
    p.add_argument("--reference-method", help="only the references solved by this method")
    p.add_argument("--out", help="report directory (default: STORE/compare-METHOD)")
    _add_dask_arguments(p)
    return parser


def _add_solver_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tol", type=float, help="bound on every relative KKT residual of the answer")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa's step (uzawa only; default: automatic)")
    p.add_argument("--time-limit", type=float, help="wall-clock limit of the solve in seconds")
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="any option of the method (value in TOML syntax), e.g. --option polish=false")


def _add_dask_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786 "
                                       "(default: start a local cluster)")
    p.add_argument("--workers", type=int, help="local cluster size (default: one worker per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _parse_value(text: str) -> Any:
    """A TOML value (``1e-8``, ``true``, ``"splu"``), or the bare text as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def command_line_options(args: argparse.Namespace) -> dict[str, Any]:
    """The solver options given on the command line, keyed by option name."""
    options: dict[str, Any] = {}
    for item in args.option:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise InputError("--option", f"expected NAME=VALUE, got {item!r}")
        options[name] = _parse_value(value.strip())
    for flag, name in OPTION_FLAGS.items():
        value = getattr(args, name)
        if value is not None:
            options[name] = value
    return options


def _flag_names(exc: InputError) -> InputError:
    """Name a command-line option by its flag (``--max-iter``, not ``max_iter``)."""
    flags = {name: flag for flag, name in OPTION_FLAGS.items()}
    return InputError(flags.get(exc.field, f"--option {exc.field}"), exc.message)


def _solve(args: argparse.Namespace) -> int:
    from .discretize import discretize
    from .output import check_output_dir, write_results
    from .problem import problem_from_dict, read_toml
    from .solvers import get_method, method_options, solver_settings, solve

    path = Path(args.problem) if args.problem else default_problem_path()
    data = read_toml(path)
    method, options = solver_settings(data.get("solver", {}))  # the file's [solver] table, checked
    if args.method is not None:
        method = get_method(args.method, "--method").name
    given = command_line_options(args)
    try:
        opts = method_options(method, given)  # the flags alone, named as flags
    except InputError as exc:
        raise _flag_names(exc) from None
    opts = method_options(method, {**options, **given, "progress": not args.quiet}, prefix="solver.")
    check_output_dir(args.out, "--out")  # before any work
    problem = problem_from_dict(data, base_dir=path.parent)
    disc = discretize(problem)
    if not args.quiet:
        print(f"{path.name}: {disc.dim}D, {disc.n_elements} elements, {disc.mesh.n_nodes} nodes, "
              f"{disc.n_contact} contact nodes; method {method}", file=sys.stderr)
    sol = solve(disc, method, opts)
    data = write_results(args.out, disc, sol)
    print(f"{sol.status.value}: U = {sol.U:.6g}, max contact pressure = {data['max_contact_pressure']:.6g}, "
          f"contact radius = {data['contact_radius']:.4g}, plastic volume = {100 * data['plastic_volume_fraction']:.2f}%")
    print(f"KKT worst residual {sol.kkt.worst:.2e}, duality gap {sol.duality_gap:.2e}, "
          f"{sol.iterations} iterations, {sol.time_s:.2f} s -> {Path(args.out) / 'summary.json'}")
    if not sol.converged:
        print(f"not converged: {sol.message}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _campaign(args: argparse.Namespace) -> int:
    from .campaign import load_campaign, run_campaign
    from .store import Store

    campaign = load_campaign(args.campaign)
    run = run_campaign(campaign, args.out, scheduler=args.scheduler, n_workers=args.workers,
                       progress=not args.quiet, retry_failed=args.retry_failed)
    ids = {c.case_id for c in campaign.cases}
    statuses = [r["status"] for r in Store(args.out).rows() if r["id"] in ids]
    failed = sum(s != "converged" for s in statuses)
    print(f"{campaign.name}: {len(ids)} cases, {len(run.statuses)} run, {len(run.skipped)} already stored; "
          f"{len(statuses) - failed} converged, {failed} failed -> {Path(args.out) / 'index.sqlite'}")
    if campaign.n_duplicates:
        print(f"note: {campaign.n_duplicates} sweep point(s) resolved to the same input as an earlier one", file=sys.stderr)
    for case_id, status in run.failed.items():
        print(f"failed: {case_id[:12]} {status}: {Store(args.out).row(case_id)['error']}", file=sys.stderr)
    return EXIT_OK if failed == 0 and len(statuses) == len(ids) else EXIT_NOT_CONVERGED


def _compare(args: argparse.Namespace) -> int:
    from .campaign import compare
    from .solvers import method_options

    options = command_line_options(args)
    try:
        method_options(args.method, options)
    except InputError as exc:
        raise _flag_names(exc) if exc.field != "method" else InputError("--method", exc.message) from None
    report = compare(args.store, args.method, options=options, reference_method=args.reference_method, out=args.out,
                     scheduler=args.scheduler, n_workers=args.workers, progress=not args.quiet)
    print(report.markdown(), end="")
    out = Path(args.out) if args.out else Path(args.store) / f"compare-{report.method}"
    print(f"-> {out / 'report.md'}, {out / 'compare.png'}, {out / 'compare.json'}", file=sys.stderr)
    return EXIT_OK if report.summary["n_converged"] == report.summary["n_cases"] else EXIT_NOT_CONVERGED


COMMANDS = {"solve": _solve, "campaign": _campaign, "compare": _compare}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code instead of raising for bad input."""
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda msg, *a, **k: print(f"warning: {msg}", file=sys.stderr)
        try:
            args = build_parser().parse_args(argv)
            return COMMANDS[args.command](args)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_INPUT
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except MemoryError:
            print("error: out of memory (the problem is too large for this machine; try a coarser mesh "
                  "or another method)", file=sys.stderr)
            return EXIT_INTERNAL
        except Exception as exc:  # a bug: one line, the traceback on request
            if os.environ.get("ELASTOPLAST_DEBUG"):
                raise
            print(f"error: internal error, {type(exc).__name__}: {exc} (please report it; ELASTOPLAST_DEBUG=1 "
                  "shows the traceback)", file=sys.stderr)
            return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
