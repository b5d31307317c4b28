"""``elastoplast compare SUITE_DIR --method M ... --out DIR``: the command's arguments,
its table and its exit code; the suite itself runs in :mod:`elastoplast.studies.suite`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from elastoplast.cli.exits import EXIT_NOT_CONVERGED, EXIT_OK
from elastoplast.errors import InputError
from elastoplast.studies.suite import profile_markdown, run_suite


#: the command line's names of run_suite's arguments
_FLAGS = {"suite_dir": "SUITE_DIR", "methods": "--method", "out": "--out", "tol": "--tol",
          "time_limit": "--time-limit", "scheduler": "--scheduler", "workers": "--workers", "rho": "--rho",
          "max_iter": "--max-iter"}


def suite_command(args: argparse.Namespace, options: dict[str, Any]) -> int:
    """``elastoplast compare SUITE_DIR --method M ... --out DIR``: prints the table of
    ``profile.md``; exit 0 when every method solved every instance, else 1. ``options``:
    the solver options of the command line (``--tol``, ``--option NAME=VALUE``, ...)."""
    if args.out is None:
        raise InputError("--out", "required with a folder of problem files (the profile's folder)")
    if args.reference_method is not None:
        raise InputError("--reference-method", "applies to a campaign store, not to a folder of problem files")
    options = dict(options)
    tol = options.pop("tol", 1e-6)
    time_limit = options.pop("time_limit", None)
    try:
        record = run_suite(args.store, args.method, out=args.out, tol=tol, time_limit=time_limit, options=options,
                           scheduler=args.scheduler, n_workers=args.workers, progress=not args.quiet)
    except InputError as exc:
        if exc.field in _FLAGS:
            raise InputError(_FLAGS[exc.field], exc.message) from None
        if exc.field.startswith("--") or ".toml: " in exc.field:  # a flag, or a problem file of the suite
            raise
        raise InputError(f"--option {exc.field}", exc.message) from None
    print(profile_markdown(record), end="")
    out = Path(args.out)
    print(f"-> {out / 'profile.md'}, {out / 'profile.png'}, {out / 'profile.json'}", file=sys.stderr)
    every = all(t is not None for per in record["times"].values() for t in per.values())
    return EXIT_OK if every else EXIT_NOT_CONVERGED
