"""Command line: ``elastoplast solve [PROBLEM.toml] --method M --out DIR``,
``elastoplast campaign CAMPAIGN.toml --out DIR [--scheduler ADDRESS]`` and
``elastoplast compare DIR --method M``.

Exit codes: 0 solved and certified, 1 the solver did not converge (the status
says why; files are still written), 2 bad input (one line naming the field),
3 an internal error (a bug: one line; ``ELASTOPLAST_DEBUG=1`` shows the
traceback), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM: ``timeout``, a batch
scheduler; it takes effect when Python regains control, after a native solver call in
progress); an interrupted or terminated run leaves no staged output behind; 141 when
stdout was closed by its reader (the run goes on and its output files are written).

Every solver option reaches the method through one path
(:func:`elastoplast.solvers.registry.method_options`): ``--tol``, ``--max-iter``,
``--rho`` and ``--time-limit`` are shorthands for ``--option NAME=VALUE``, which
sets any option of the chosen method; the file's ``[solver]`` table comes
first and the command line wins.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import tomllib
import warnings
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

from elastoplast.errors import InputError

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 3, 130, 143
#: stdout closed by its reader (``elastoplast ... | head``): the shell's code for SIGPIPE
EXIT_BROKEN_PIPE = 141

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
    from elastoplast.solvers.registry import METHODS

    parser = _Parser(prog="elastoplast", description="Reference solutions of an elasto-plastic contact problem.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("solve", help="solve one problem and write solution.vtu and summary.json")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--method", help=f"solver, one of {sorted(METHODS)} (default: the file's [solver] method, else conic)")
    p.add_argument("--out", default="results", help="output folder, new or holding an earlier output (default: results)")
    _add_solver_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("bounds", help="certified bounds on the continuous problem: energy, stress error and U")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--method", help="solver of the P1 solution (default: the file's [solver] method, else conic)")
    p.add_argument("--out", default="bounds", help="output folder (default: bounds)")
    _add_solver_arguments(p, time_help="wall-clock limit of the P1 solve in seconds (the bound programs are not "
                                       "limited; 'adapt --time-limit' budgets a whole run)")
    p.add_argument("--no-bracket", action="store_true", help="no U bracket (it costs two more lower-bound programs)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("limit", help="bracket the limit load of perfect plasticity (hardening = 0)")
    p.add_argument("problem", help="problem TOML file with hardening = 0")
    p.add_argument("--out", default="limit", help="output folder (default: limit)")
    p.add_argument("--order", type=int, help="degree of the kinematic velocity field, 1 or 2 (default: 2)")
    p.add_argument("--time-limit", type=float, help="wall-clock limit of each of the two programs, seconds")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("adapt", help="refine where the certified gap is until the relative gap is at most --rtol")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--rtol", type=float, help="target relative energy gap (default: 1e-3)")
    p.add_argument("--theta", type=float, help="Dörfler parameter (default: 0.5)")
    p.add_argument("--max-elements", type=int, help="element budget (default: 2,000,000)")
    p.add_argument("--time-limit", type=float, help="time budget in seconds, checked between meshes (the first mesh "
                                                    "is always solved and bounded)")
    p.add_argument("--method", help="solver of the P1 solutions (default: newton)")
    p.add_argument("--bracket", choices=["every", "final", "never"],
                   help="U bracket on the final mesh (default), at every step, or none")
    p.add_argument("--no-uniform", action="store_true", help="skip the uniform-refinement comparison")
    p.add_argument("--out", default="adapt", help="output folder (default: adapt)")
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


def _add_solver_arguments(p: argparse.ArgumentParser, time_help: str = "wall-clock limit of the solve in seconds") -> None:
    p.add_argument("--tol", type=float, help="bound on every relative KKT residual of the answer")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa's step (uzawa only; default: automatic)")
    p.add_argument("--time-limit", type=float, help=time_help)
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


def _setup(args: argparse.Namespace, method_flag: bool = True):
    """What every command on one problem starts with: the problem file (or the
    built-in default), its ``[solver]`` table and the command-line options, all
    checked, and ``--out`` checked, before any work. Returns ``(path, data,
    method, options)``."""
    from elastoplast.io.output import check_output_dir
    from elastoplast.problem.definition import read_toml
    from elastoplast.solvers.registry import get_method, method_options, solver_settings

    path = Path(args.problem) if args.problem else default_problem_path()
    data = read_toml(path)
    method, options = solver_settings(data.get("solver", {}))  # the file's [solver] table, checked
    if method_flag and args.method is not None:
        method = get_method(args.method, "--method").name
    given = command_line_options(args) if method_flag else {}
    try:
        method_options(method, given)  # the flags alone, named as flags
    except InputError as exc:
        raise _flag_names(exc) from None
    opts = method_options(method, {**options, **given, "progress": not args.quiet}, prefix="solver.")
    check_output_dir(args.out, "--out")
    return path, data, method, opts


def _discretize(path: Path, data: dict, quiet: bool, what: str):
    from elastoplast.fem.discretize import discretize
    from elastoplast.problem.definition import problem_from_dict

    disc = discretize(problem_from_dict(data, base_dir=path.parent))
    if not quiet:
        print(f"{path.name}: {disc.dim}D, {disc.n_elements} elements, {disc.mesh.n_nodes} nodes, "
              f"{disc.n_contact} contact nodes; {what}", file=sys.stderr)
    return disc


def _solve(args: argparse.Namespace) -> int:
    from elastoplast.cli.results import write_results
    from elastoplast.solvers.registry import solve

    path, data, method, opts = _setup(args)
    disc = _discretize(path, data, args.quiet, f"method {method}")
    sol = solve(disc, method, opts)
    data = write_results(args.out, disc, sol, field="--out")
    print(f"{sol.status.value}: U = {sol.U:.6g}, max contact pressure = {data['max_contact_pressure']:.6g}, "
          f"contact radius = {data['contact_radius']:.4g}, plastic volume = {100 * data['plastic_volume_fraction']:.2f}%")
    print(f"KKT worst residual {sol.kkt.worst:.2e}, duality gap {sol.duality_gap:.2e}, "
          f"{sol.iterations} iterations, {sol.time_s:.2f} s -> {Path(args.out) / 'summary.json'}")
    if not sol.converged:
        print(f"not converged: {sol.message}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _bounds(args: argparse.Namespace) -> int:
    from elastoplast.bounds.bracket import certified_bounds, gap_fields
    from elastoplast.bounds.lower import (
        SEQUENCE_MEMORY_FACTOR,
        LowerBoundOptions,
        check_lower_bound_size,
    )
    from elastoplast.certificate.solution import Status
    from elastoplast.cli.results import write_results
    from elastoplast.solvers.registry import check_solvable, solve

    path, data, method, opts = _setup(args)
    disc = _discretize(path, data, args.quiet, f"P1 solution by {method}, then the bounds")
    # before the solve; the U bracket runs two more programs in this process
    check_lower_bound_size(disc, LowerBoundOptions(), factor=1.0 if args.no_bracket else SEQUENCE_MEMORY_FACTOR)
    check_solvable(disc, method, opts)
    sol = solve(disc, method, opts)
    if sol.status is Status.INFEASIBLE:
        raise InputError("load.force", f"{disc.force:g} is above the limit load ({sol.message}): the problem has "
                                       "no solution to bound; 'elastoplast limit' brackets the limit load")
    if not sol.converged:
        print(f"warning: the P1 solution did not converge ({sol.message}); its upper bound stays valid, only looser",
              file=sys.stderr)
    report = certified_bounds(disc, sol, method, bracket=not args.no_bracket, options=opts)
    b = report.bounds
    write_results(args.out, disc, sol, extra=report.as_dict(), field="--out", **gap_fields(disc, b))
    bracket = "" if args.no_bracket else f"; U in [{report.U_lower:.6g}, {report.U_upper:.6g}]"
    print(f"energy in [{b.energy_lower:.8g}, {b.energy_upper:.8g}] (relative gap {b.energy_gap_rel:.2e}){bracket}"
          f" (discrete U = {sol.U:.6g}); stress error <= {b.stress_error_bound:.4g} "
          f"({100 * b.stress_error_bound_rel:.2f}%); {'certified' if report.certified else 'NOT certified'}"
          f" -> {Path(args.out) / 'summary.json'}")
    if not report.certified:
        print(f"not certified: upper: {report.upper.message}; lower: {report.lower.message}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return EXIT_OK


def _limit(args: argparse.Namespace) -> int:
    from elastoplast.bounds.limit import LimitOptions, limit_load
    from elastoplast.bounds.lower import LowerBoundOptions
    from elastoplast.io.output import json_text, staged_output

    path, data, _, _ = _setup(args, method_flag=False)
    warnings.filterwarnings("ignore", message=r".*hardening = 0 is perfect plasticity")  # what 'limit' is for
    given = {k: v for k, v in (("order", args.order), ("time_limit", args.time_limit)) if v is not None}
    try:
        options = LimitOptions.build(given)
    except InputError as exc:
        raise InputError(f"--{exc.field.replace('_', '-')}", exc.message) from None
    disc = _discretize(path, data, args.quiet, "limit load bracket (H = 0)")
    bracket = limit_load(disc, options, LowerBoundOptions(time_limit=options.time_limit))
    with staged_output(args.out, "--out") as tmp:
        from elastoplast.io.provenance import stamp

        (tmp / "summary.json").write_text(json_text({**bracket.as_dict(), "provenance": stamp()}))
    print(f"{bracket.F_lower:.6g} <= F_c <= {bracket.F_upper:.6g} (ratio {bracket.ratio:.4f}); "
          f"{'certified' if bracket.certified else 'NOT certified'} -> {Path(args.out) / 'summary.json'}")
    if bracket.message:
        print(bracket.message, file=sys.stderr)
    return EXIT_OK if bracket.certified else EXIT_NOT_CONVERGED


def _adapt(args: argparse.Namespace) -> int:
    from elastoplast.adapt.loop import check_adaptable
    from elastoplast.adapt.records import AdaptOptions
    from elastoplast.cli.adapt import run_adapt_command
    from elastoplast.solvers.registry import get_method

    path, data, method, _ = _setup(args, method_flag=False)
    if args.method is not None:
        method = get_method(args.method, "--method").name
    elif "method" not in data.get("solver", {}):
        method = AdaptOptions().method  # Newton: the fastest P1 solver (benchmarks/methods)
    # of the file's [solver] table, the method and the P1 tolerance apply; nothing is dropped silently
    table = data.get("solver", {})
    from_file = {"tol": table["tol"]} if "tol" in table else {}
    AdaptOptions.build(from_file, prefix="solver.")  # the range of adapt's P1 tolerance, named as written
    unused = [f"solver.{k}" for k in table if k not in ("method", "tol")]
    if unused:
        warnings.warn(f"{', '.join(unused)}: not used by adapt, which sets its own P1 solves (of [solver], method "
                      "and tol apply)")
    given = {k: v for k, v in (("rtol", args.rtol), ("theta", args.theta), ("max_elements", args.max_elements),
                               ("time_limit", args.time_limit), ("bracket", args.bracket)) if v is not None}
    given = {**from_file, **given}
    if args.no_uniform:
        given["compare_uniform"] = False
    try:
        options = AdaptOptions.build({**given, "method": method, "progress": not args.quiet})
    except InputError as exc:
        raise InputError(f"--{exc.field.replace('_', '-')}", exc.message) from None
    disc = _discretize(path, data, args.quiet, f"adaptive refinement to rtol {options.rtol:g}")
    check_adaptable(disc.problem)
    return EXIT_OK if run_adapt_command(disc.problem, options, args.out) else EXIT_NOT_CONVERGED


def _campaign(args: argparse.Namespace) -> int:
    from elastoplast.cli.campaign import load_campaign, run_campaign
    from elastoplast.io.store import Store

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
    from elastoplast.cli.compare import compare
    from elastoplast.solvers.registry import method_options

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


COMMANDS = {"solve": _solve, "bounds": _bounds, "limit": _limit, "adapt": _adapt, "campaign": _campaign,
            "compare": _compare}


class Terminated(BaseException):
    """SIGTERM, raised where the program is, so that it unwinds like Ctrl-C: the
    ``finally`` blocks run and staged output folders are removed (Python's default
    SIGTERM ends the process on the spot, leaving them behind)."""


def _raise_terminated(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not interrupt the unwinding
    raise Terminated()


class _GuardedStdout:
    """``sys.stdout`` whose reader may go away (``elastoplast ... | head``): the first
    ``BrokenPipeError`` sends the rest to ``os.devnull`` and the command carries on, so
    a run still inside its staged output folder writes its files; ``broken`` says so."""

    def __init__(self, stream):
        self._stream, self.broken = stream, False

    def _gone(self) -> None:
        self.broken = True
        with contextlib.suppress(OSError, ValueError, AttributeError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._gone()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._gone()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


@contextlib.contextmanager
def _guarded_stdout():
    guard = _GuardedStdout(sys.stdout)
    sys.stdout = guard
    try:
        yield guard
    finally:
        if sys.stdout is guard:
            sys.stdout = guard._stream


@contextlib.contextmanager
def _sigterm_unwinds():
    """SIGTERM raises :class:`Terminated` while the command runs (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code instead of raising for bad input."""
    with warnings.catch_warnings(), _sigterm_unwinds(), _guarded_stdout() as out:
        warnings.simplefilter("always")
        warnings.showwarning = lambda msg, *a, **k: print(f"warning: {msg}", file=sys.stderr)
        try:
            args = build_parser().parse_args(argv)
            code = COMMANDS[args.command](args)
            return EXIT_BROKEN_PIPE if out.broken else code
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_INPUT
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Terminated:
            print("terminated", file=sys.stderr)
            return EXIT_TERMINATED
        except BrokenPipeError:  # the files are written; only the report's reader has gone
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
            return EXIT_BROKEN_PIPE
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
