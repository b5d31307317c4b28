"""Command line: ``elastoplast solve [PROBLEM.toml] --method M --out DIR``,
``elastoplast campaign CAMPAIGN.toml --out DIR [--scheduler ADDRESS]``,
``elastoplast compare DIR --method M``, ``elastoplast options [M]`` (the options
behind ``--option``) and ``elastoplast --version``.

Exit codes: 0 solved and certified, 1 the solver did not converge (the status
says why; files are still written), 2 bad input (one line naming the field),
3 an internal error (a bug, or a plug-in method that raised or called
``sys.exit()`` in its run: one line; ``ELASTOPLAST_DEBUG=1`` shows the traceback;
an output folder on a full disk, over quota, read-only or past a file-size limit is 2), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM: ``timeout``, a batch
scheduler; it takes effect when Python regains control, after a native solver call in
progress); an interrupted or terminated run leaves no staged output behind; 141 when
stdout was closed by its reader (the run goes on and its output files are written).

Every solver option reaches the method through one path
(:func:`elastoplast.solvers.registry.method_options`): ``--tol``, ``--max-iter``,
``--rho`` and ``--time-limit`` are shorthands for ``--option NAME=VALUE``, which
sets any option of the chosen method; the file's ``[solver]`` table comes
first and the command line wins. A ``--method`` other than the file's drops the
file's options that method does not have, with a note.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import warnings
from typing import Sequence

from elastoplast.errors import InputError
from elastoplast.cli.commands import COMMANDS
from elastoplast.cli.exits import EXIT_BROKEN_PIPE, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_TERMINATED



class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # usage errors are input errors: exit 2, one line
        self.print_usage(sys.stderr)
        raise InputError("arguments", message)  # a 50,000-character flag in it is cut in the middle


def build_parser() -> argparse.ArgumentParser:
    from elastoplast.solvers.registry import METHODS
    from elastoplast.version import __version__

    parser = _Parser(prog="elastoplast", description="Reference solutions of an elasto-plastic contact problem.")
    parser.add_argument("-V", "--version", action="version", version=f"elastoplast {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("solve", help="solve one problem and write solution.vtu and summary.json; a problem with a "
                                     "loading path ([load] path): every step, solution_NNN.vtu, path.pvd, path.png")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--method", help=f"solver, one of {sorted(METHODS)} (default: the file's [solver] method, else conic)")
    p.add_argument("--out", default="results", help="output folder, new or holding an earlier output (default: results)")
    _add_solver_arguments(p, time_help="wall-clock limit in seconds of the whole run: the solve, every step of a "
                                       "loading path together (the path stops with status time_limit once spent), "
                                       "or every solve of a depth control's force search together")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("bounds", help="certified bounds on the continuous problem: energy, stress error and U")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--method", help="solver of the P1 solution (default: the file's [solver] method, else conic, or "
                                    "newton on a mesh beyond the conic reference's size, with a note)")
    p.add_argument("--out", default="bounds", help="output folder (default: bounds)")
    _add_solver_arguments(p, time_help="wall-clock limit of the P1 solve in seconds (the bound programs are not "
                                       "limited; 'adapt --time-limit' budgets a whole run)")
    p.add_argument("--no-bracket", action="store_true", help="no U bracket (it costs two more lower bounds)")
    _add_lower_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("limit", help="bracket the limit load of perfect plasticity (hardening = 0)")
    p.add_argument("problem", help="problem TOML file with hardening = 0")
    p.add_argument("--out", default="limit", help="output folder (default: limit)")
    p.add_argument("--order", type=int, help="degree of the kinematic velocity field, 1 or 2 (default: 2)")
    p.add_argument("--time-limit", type=float, help="wall-clock budget in seconds of the whole bracket: the kinematic "
                                                    "program, then the static one with what is left (Clarabel checks it "
                                                    "between iterations; a bound it stops is not certified)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("adapt", help="refine where the certified gap is until the relative gap is at most --rtol")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--rtol", type=float, help="target relative energy gap (default: 1e-3)")
    p.add_argument("--theta", type=float, help="Dörfler parameter (default: 0.5)")
    p.add_argument("--min-growth", type=float, help="raise θ until each new mesh has at least this many times the "
                                                    "elements (default: 1.5; 1 keeps θ)")
    p.add_argument("--max-elements", type=int, help="element budget (default: 2,000,000)")
    p.add_argument("--time-limit", type=float, help="time budget in seconds, checked between meshes (the first mesh "
                                                    "is always solved and bounded)")
    p.add_argument("--method", help="solver of the P1 solutions (default: newton)")
    p.add_argument("--bracket", choices=["every", "final", "never"],
                   help="U bracket on the final mesh (default), at every step, or none")
    p.add_argument("--no-uniform", action="store_true", help="skip the uniform-refinement comparison")
    _add_lower_argument(p)
    p.add_argument("--out", default="adapt", help="output folder (default: adapt)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("campaign", help="run a sweep of problems on Dask into a resumable store of reference solutions",
                       description="Run a sweep of problems on Dask into a resumable store of reference solutions. "
                                   "Time limits: each case's solve is bounded by the campaign file's [solver] "
                                   "time_limit in seconds (a loading path's steps together; also a sweep axis, "
                                   "\"solver.time_limit\"), the case then stored with status time_limit; the "
                                   "campaign as a whole has no limit (interrupt it and run it again: it resumes).")
    p.add_argument("campaign", help="campaign TOML file: a base problem and [sweep] axes")
    p.add_argument("--out", required=True, help="store directory (created; re-running skips the cases it holds)")
    _add_dask_arguments(p)
    p.add_argument("--retry-failed", action="store_true", help="also re-run stored cases the solver did not solve")

    p = sub.add_parser("compare", help="run a method on every stored reference case and report its errors; or, "
                                       "on a folder of problem files, several methods and their performance profile")
    p.add_argument("store", help="store directory written by 'elastoplast campaign', or a folder of problem files "
                                 "(*.toml, no index.sqlite): a suite of instances")
    p.add_argument("--method", required=True, action="append",
                   help=f"method to compare (one of {sorted(METHODS)}); on a suite folder, repeat it for each method")
    _add_solver_arguments(p, time_help="wall-clock limit of each case's solve in seconds (not of the comparison)")
    p.add_argument("--reference-method", help="only the references solved by this method")
    p.add_argument("--out", help="report directory (default: STORE/compare-METHOD; required for a suite folder)")
    _add_dask_arguments(p)

    p = sub.add_parser("options", help="list each method's options (set with --option NAME=VALUE) with type, "
                                       "default and range")
    p.add_argument("method", nargs="?", help=f"only this method's (one of {sorted(METHODS)})")

    p = sub.add_parser("check", help="certify an answer computed anywhere (an .npz of u and U, or a solution.vtu) "
                                     "by the KKT certificate")
    p.add_argument("problem", help="problem TOML file the answer is for")
    p.add_argument("answer", help="ANSWER: an .npz with u (n_nodes x d) and U, optionally sigma and xi; or a .vtu "
                                  "with point data displacement (U: field data, or the summary.json beside it; for a "
                                  "path's solution_NNN.vtu, step NNN's entry)")
    p.add_argument("--tol", type=float, help="bound on every relative KKT residual (default: the file's solver.tol, "
                                             "else 1e-6)")
    p.add_argument("--bounds", action="store_true", help="also the continuum upper bound of the answer's field and "
                                                         "the energy and U brackets (three lower-bound programs)")
    p.add_argument("--out", help="write summary.json and solution.vtu into this folder (default: nothing is written)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("export", help="write the discrete problem (2.1) as a conic program for any solver "
                                      "(CBF version 3, or Clarabel/SCS's form in .npz), with a JSON map back")
    p.add_argument("problem", nargs="?", help="problem TOML file (default: the built-in 3D sphere on a block)")
    p.add_argument("--format", default="cbf", choices=["cbf", "npz"], help="file format (default: cbf)")
    p.add_argument("--form", default="S", choices=["S", "D"], help="the stress form (S) or the displacement "
                                                                   "form (D) (default: S)")
    p.add_argument("--energy", default="cone", choices=["cone", "quadratic"],
                   help="the energy in a rotated quadratic cone (default), or as P (npz only)")
    p.add_argument("--out", required=True, help="output file; the map back is written beside it as OUT.json (an "
                                                "earlier export there is replaced, any other file refused)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return parser


def _add_solver_arguments(p: argparse.ArgumentParser, time_help: str = "wall-clock limit of the solve in seconds") -> None:
    p.add_argument("--tol", type=float, help="bound on every relative KKT residual of the answer")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa's step (uzawa only; default: automatic)")
    p.add_argument("--time-limit", type=float, help=time_help)
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="any option of the method (value in TOML syntax), e.g. --option polish=false; "
                        "'elastoplast options METHOD' lists them")


def _add_lower_argument(p: argparse.ArgumentParser) -> None:
    from elastoplast.bounds.local.construction import DESCENT_STEPS
    from elastoplast.bounds.lower import AUTO_GLOBAL_MAX_ELEMENTS, LOWER_BOUND_KINDS

    p.add_argument("--lower", choices=LOWER_BOUND_KINDS,
                   help="the lower bound: 'global', the optimum of the equilibrium element (a conic program; "
                        "the only one with hardening = 0; its cost grows fast, refused above 25,000 tetrahedra), "
                        "'local', an admissible field built from the P1 solution in passes over the mesh "
                        "(hardening > 0; no global program), or 'auto' (default): global with "
                        "hardening = 0 and up to "
                        f"{AUTO_GLOBAL_MAX_ELEMENTS[2]:,} triangles or {AUTO_GLOBAL_MAX_ELEMENTS[3]:,} tetrahedra, "
                        "local above")
    p.add_argument("--descent", type=int, metavar="STEPS",
                   help="the local lower bound's steps over all patches together after its sweeps (default: "
                        f"{DESCENT_STEPS[2]}, fewer once they gain little against the gap; 0: the sweeps alone, "
                        "faster and looser; more: tighter where plastic zones stall the sweeps; refused with "
                        "hardening = 0 or --lower global, noted where auto chooses the global program)")


def _add_dask_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786 "
                                       "(default: start a local cluster)")
    p.add_argument("--workers", type=int, help="local cluster size (default: one worker per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


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


def _show_warning(message, category=None, *args, **kwargs) -> None:
    """A warning on a line of its own, above any progress bar (tqdm clears and redraws it).
    numpy's floating-point warnings (overflow, invalid value, divide by zero; a RuntimeWarning
    "... encountered in ...") are said once per kind and run, marked as arithmetic: they arrive
    in bursts, one per array operation, and the answer's own checks judge what they mean."""
    from tqdm import tqdm

    text = str(message)
    if category is not None and issubclass(category, RuntimeWarning) and " encountered in " in text:
        if text in _SAID:
            return
        _SAID.add(text)
        text = f"floating-point arithmetic: {text} (said once; the certificate and status judge the answer)"
    tqdm.write(f"warning: {text}", file=sys.stderr)


#: numpy's warnings said in this run (one line per kind)
_SAID: set[str] = set()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code instead of raising for bad input."""
    with warnings.catch_warnings(), _sigterm_unwinds(), _guarded_stdout() as out:
        warnings.simplefilter("always")
        warnings.showwarning = _show_warning
        _SAID.clear()
        try:
            try:
                args = build_parser().parse_args(argv)
            except SystemExit as exc:  # --help, --version: printed, and done
                return exc.code if isinstance(exc.code, int) else EXIT_OK
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
