"""Side study: the local lower bound against the newton solve at 100k, 300k and 1M tetrahedra.

    python benchmarks/bounds/local_scale.py [--quick] [--out DIR] [--report]

The default 3D problem (problems/sphere_block_3d.toml) at 98,304, 292,008 and 1,029,000
tetrahedra. Per size, each in its own process (so that its peak memory, VmHWM, is its own):
``newton``, the P1 solve alone at its default tolerance (the reference of the issue's
targets: time and memory of the solve); ``local``, the P1 solve to the local bound's
tolerance (bracket.LOCAL_SOLVE_TOL, as `bounds` asks), the certified upper bound, then the
local bound with its sweeps alone (``descent=0``: the same setting at every size, so that the
growth is comparable; `bounds` also runs it so where the descent does not fit, as at 1M on
this machine, bracket.local_descent). The report gives the ratios of the local bound's time
and of the local process's peak to newton's, and the exponents of time ~ n^a fitted by least
squares in log-log over the sizes. Writes ``local_scale.json`` and ``local_scale.md`` beside
this file (``--quick``: 1,536 and 12,288 tetrahedra, in ``benchmarks/bounds/quick/``).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record, shipped_problem  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STUDY = "local_scale"
TITLE = "Local lower bound against the newton solve, 100k to 1M tetrahedra"
PROBLEM = "sphere_block_3d"
SIZES = [(32, 32, 16), (46, 46, 23), (70, 70, 35)]
QUICK = [(8, 8, 4), (16, 16, 8)]


def run_one(divisions, what: str) -> dict:
    import elastoplast as ep
    from elastoplast.references.solves import LOCAL_SOLVE_TOL
    from elastoplast.bounds.local.construction import local_lower_bound
    from elastoplast.references.solves import best_upper_bound

    disc = shipped_problem(PROBLEM, divisions)
    out = {"n_elements": int(disc.n_elements)}
    t0 = time.perf_counter()
    if what == "newton":
        sol = ep.solve(disc, "newton")
        out.update(newton_s=time.perf_counter() - t0, converged=sol.converged, kkt=sol.kkt.worst)
    else:
        sol = ep.solve(disc, "newton", tol=LOCAL_SOLVE_TOL)
        out.update(solve_s=time.perf_counter() - t0, kkt=sol.kkt.worst)
        t1 = time.perf_counter()
        up = best_upper_bound(disc, sol, method="newton")
        out.update(upper_s=time.perf_counter() - t1, upper=up.Pi, upper_certified=up.certified)
        t1 = time.perf_counter()
        lb = local_lower_bound(disc, sol, descent=0)
        out.update(local_s=time.perf_counter() - t1, lower=lb.lower, certified=lb.certified,
                   certificate_worst=lb.certificate.worst, message=lb.message, timings=lb.timings,
                   gap_rel=(up.Pi - lb.lower) / abs(up.Pi))
    out["peak_rss_mb"] = peak_memory() / 2**20
    return out


def fitted_exponent(n, t) -> float:
    """The slope of log t against log n (least squares); nan with fewer than two sizes."""
    n, t = np.asarray(n, dtype=float), np.asarray(t, dtype=float)
    ok = np.isfinite(t) & (t > 0)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)[0])


def report(results: dict) -> str:
    lines = ["Each run in its own process; seconds (wall clock); MB the process's peak (VmHWM). `newton` is the solve",
             "alone at its default tolerance; `local` the local bound's own time (sweeps alone, then the repair, the",
             "lift and the certificate), after a solve to 1e-13 and the upper bound, which its process also ran.",
             "",
             "| tetrahedra | newton s | local s | local / newton | newton MB | local process MB | MB ratio | "
             "sweeps s | relative gap | certified | worst residual |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = []
    for r in results["cases"]:
        nw, lo = r["newton"], r["local"]
        if "error" in nw or "error" in lo:
            lines.append(f"| {r['divisions']} | error: {nw.get('error', '')} {lo.get('error', '')} |")
            continue
        rows.append((nw["n_elements"], nw["newton_s"], lo["local_s"], nw["peak_rss_mb"], lo["peak_rss_mb"]))
        lines.append(f"| {nw['n_elements']:,} | {nw['newton_s']:.1f} | {lo['local_s']:.1f} | "
                     f"{lo['local_s'] / nw['newton_s']:.1f} | {nw['peak_rss_mb']:.0f} | {lo['peak_rss_mb']:.0f} | "
                     f"{lo['peak_rss_mb'] / nw['peak_rss_mb']:.1f} | {lo['timings'].get('sweeps', float('nan')):.1f} | "
                     f"{lo['gap_rel']:.3g} | {lo['certified']} | {lo['certificate_worst']:.1e} |")
    if rows:
        n, tn, tl, mn, ml = (np.array(c) for c in zip(*rows))
        lines += ["", f"Fitted growth, time ~ n^a: newton a = {fitted_exponent(n, tn):.2f}, local bound "
                      f"a = {fitted_exponent(n, tl):.2f}; peak memory: newton {fitted_exponent(n, mn):.2f}, "
                      f"local process {fitted_exponent(n, ml):.2f}."]
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    results = {"cases": []}
    for div in (QUICK if mode == "quick" else SIZES):
        case = {"problem": PROBLEM, "divisions": list(div)}
        for what in ("newton", "local"):
            case[what] = run_child(__file__, [list(div), what], cwd=ROOT)
        results["cases"].append(case)
        print(json.dumps(case), flush=True)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "1,536 and 12,288 tetrahedra", HERE, TITLE, "local bound at scale", measure,
                      report, argv=argv, study=STUDY, child=lambda spec: run_one(*spec))


if __name__ == "__main__":
    sys.exit(main())
