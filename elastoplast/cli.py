"""Command line: ``elastoplast solve [PROBLEM.toml] --method M --out DIR``.

Exit codes: 0 solved and certified, 1 the solver did not converge (the status
says why; files are still written), 2 bad input (one line naming the field).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from importlib import resources
from pathlib import Path
from typing import Sequence

from .errors import InputError

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT = 0, 1, 2


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
    p.add_argument("--method", default="conic", choices=sorted(METHODS), help="solver (default: conic)")
    p.add_argument("--out", default="results", help="output directory (default: results)")
    p.add_argument("--tol", type=float, help="solver tolerance")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa step (default: automatic)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return parser


def _solve(args: argparse.Namespace) -> int:
    import numpy as np

    from .discretize import discretize
    from .output import write_results
    from .problem import load_problem
    from .solvers import solve

    path = Path(args.problem) if args.problem else default_problem_path()
    problem = load_problem(path)
    disc = discretize(problem)
    options = {k: v for k, v in (("tol", args.tol), ("max_iter", args.max_iter), ("rho", args.rho)) if v is not None}
    if not args.quiet:
        options["progress"] = True
        print(f"{path.name}: {disc.dim}D, {disc.n_elements} elements, {disc.mesh.n_nodes} nodes, "
              f"{disc.n_contact} contact nodes; method {args.method}", file=sys.stderr)
    sol = solve(disc, args.method, **options)
    data = write_results(args.out, disc, sol)
    print(f"{sol.status.value}: U = {sol.U:.6g}, max contact pressure = {data['max_contact_pressure']:.6g}, "
          f"contact radius = {data['contact_radius']:.4g}, plastic volume = {100 * data['plastic_volume_fraction']:.2f}%")
    print(f"KKT worst residual {sol.kkt.worst:.2e}, duality gap {sol.duality_gap:.2e}, "
          f"{sol.iterations} iterations, {sol.time_s:.2f} s -> {Path(args.out) / 'summary.json'}")
    if not sol.converged:
        print(f"not converged: {sol.message}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    del np
    return EXIT_OK


COMMANDS = {"solve": _solve}


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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
