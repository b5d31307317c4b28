"""Command line: ``elastoplast solve [PROBLEM.toml] --method M --out DIR``,
``elastoplast campaign CAMPAIGN.toml --out DIR [--scheduler ADDRESS]`` and
``elastoplast compare DIR --method M``.

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
    p.add_argument("--method", choices=sorted(METHODS), help="solver (default: the file's [solver] method, else conic)")
    p.add_argument("--out", default="results", help="output directory (default: results)")
    p.add_argument("--tol", type=float, help="solver tolerance")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa step (default: automatic)")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("campaign", help="run a sweep of problems on Dask into a resumable store of reference solutions")
    p.add_argument("campaign", help="campaign TOML file: a base problem and [sweep] axes")
    p.add_argument("--out", required=True, help="store directory (created; re-running skips the cases it holds)")
    _add_dask_arguments(p)
    p.add_argument("--retry-failed", action="store_true", help="also re-run stored cases the solver did not solve")

    p = sub.add_parser("compare", help="run a method on every stored reference case and report its errors")
    p.add_argument("store", help="store directory written by 'elastoplast campaign'")
    p.add_argument("--method", required=True, help=f"method to compare (one of {sorted(METHODS)})")
    p.add_argument("--tol", type=float, help="solver tolerance")
    p.add_argument("--max-iter", type=int, help="iteration limit")
    p.add_argument("--rho", type=float, help="Uzawa step (default: automatic)")
    p.add_argument("--reference-method", help="only the references solved by this method")
    p.add_argument("--out", help="report directory (default: STORE/compare-METHOD)")
    _add_dask_arguments(p)
    return parser


def _add_dask_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", help="address of a running Dask scheduler (default: start a local cluster)")
    p.add_argument("--workers", type=int, help="local cluster size (default: one worker per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _solve(args: argparse.Namespace) -> int:
    from .discretize import discretize
    from .output import write_results
    from .problem import problem_from_dict, read_toml, solver_settings
    from .solvers import solve

    path = Path(args.problem) if args.problem else default_problem_path()
    data = read_toml(path)
    method, options = solver_settings(data.get("solver", {}))  # the file's [solver] table, checked
    problem = problem_from_dict(data, base_dir=path.parent)
    disc = discretize(problem)
    args.method = args.method or method
    options.update({k: v for k, v in (("tol", args.tol), ("max_iter", args.max_iter), ("rho", args.rho)) if v is not None})
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

    options = {k: v for k, v in (("tol", args.tol), ("max_iter", args.max_iter), ("rho", args.rho)) if v is not None}
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
