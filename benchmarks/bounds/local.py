"""Side study: the local lower bound (equilibration, exact lift, sweeps, descent) against the global program.

    python benchmarks/bounds/local.py [--quick] [--out DIR] [--report]

On the 2D cylinder (problems/cylinder_2d.toml, graded, plastic, H > 0) and the 3D quarter
sphere (problems/sphere_quarter_3d.toml) and the default 3D problem (problems/sphere_block_3d.toml) at a few sizes, each in its own process (so that
its peak memory, VmHWM, is its own): ``newton`` (the P1 solve alone, default tolerance), ``local-<S>`` and
``local-<S>+<D>`` (the P1 solve to the local bound's tolerance, bracket.LOCAL_SOLVE_TOL, as `bounds` solves it; the certified upper bound, then :func:`local_lower_bound`
with S sweeps and at most D descent steps over all rings, :data:`VARIANTS`; its timings
split into the ring set-up, the sweeps, the descent, the round-off repair and the rest;
``local_peak_rss_mb`` the process's peak after it) and ``global`` (:func:`solve_lower_bound`, the optimum of the equilibrium element on
the same mesh; never at 98,304 tetrahedra, ``NO_GLOBAL``: that size, sweeps alone, is in the
record of commit 044e342, not rerun here: the descent's 300 steps there would take about 20 minutes). The gap ratio is (upper - local) / (upper - global), both lower bounds
paired with the same upper bound. Writes ``local.json`` and ``local.md`` beside this file
(``--quick``: ``benchmarks/bounds/quick/``).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record, shipped_problem  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PROBLEMS = ROOT / "problems"
STUDY = "local"
TITLE = "Local lower bound against the global equilibrium-element program"

CASES = {"cylinder_2d": [(40, 20), (80, 40), (160, 80)], "sphere_quarter_3d": [(3, 3, 3), (6, 6, 5)],
         "sphere_block_3d": [(8, 8, 4), (16, 16, 8)]}
QUICK = {"cylinder_2d": [(24, 12)], "sphere_quarter_3d": [(3, 3, 3)]}
#: the local bounds run: ``S`` sweeps alone, or ``S+D`` sweeps then at most D descent steps over all rings
#: (the defaults of local_lower_bound: 64+300 in 2D and 3D), ``u`` with the upper bound given, so that the
#: descent also stops once it gains little against the gap (as ``bounds`` and ``adapt`` run it), ``@A`` the
#: share of the revisit rule (sweeps.ACTIVE_SHARE of the dimension; default: the package's). ``32@0.05`` is
#: the 3D sweeps setting before commit b504e77
VARIANTS = {"cylinder_2d": ("64", "64+300", "64+300u"), "sphere_quarter_3d": ("32@0.05", "64", "64+100", "64+300u"),
            "sphere_block_3d": ("32@0.05", "64", "64+100", "64+300u")}
#: the global program runs where it is allowed (3D: up to 25,000 tetrahedra) and fits the time of this study
NO_GLOBAL = {("sphere_block_3d", (32, 32, 16))}


def run_one(problem: str, divisions, what: str) -> dict:
    import elastoplast as ep
    from elastoplast.bounds.local.construction import local_lower_bound
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound
    from elastoplast.references.solves import best_upper_bound

    disc = shipped_problem(problem, divisions)
    out = {"n_elements": int(disc.n_elements)}
    t0 = time.perf_counter()
    if what == "global":
        lb = solve_lower_bound(disc)
        out.update(time_s=time.perf_counter() - t0, lower=lb.lower, certified=lb.certified,
                   certificate_worst=lb.certificate.worst)
    else:
        from elastoplast.references.solves import LOCAL_SOLVE_TOL

        # the local rows solve to the tolerance `bounds` asks for the local bound (bracket.local_solution)
        sol = ep.solve(disc, "newton", **({} if what == "newton" else {"tol": LOCAL_SOLVE_TOL}))
        out.update(newton_s=time.perf_counter() - t0, converged=sol.converged, kkt=sol.kkt.worst)
        if what.startswith("local"):
            up = best_upper_bound(disc, sol, method="newton")
            t1 = time.perf_counter()
            spec, _, share = what.split("-")[1].partition("@")
            sweeps, _, descent = spec.partition("+")
            given = descent.endswith("u")
            descent = descent.rstrip("u")
            if share:
                from elastoplast.bounds.local import sweeps

                sweeps.ACTIVE_SHARE = {**sweeps.ACTIVE_SHARE, disc.dim: float(share)}
            lb = local_lower_bound(disc, sol, int(sweeps), descent=int(descent or 0), upper=up.Pi if given else None)
            out["local_peak_rss_mb"] = peak_memory() / 2**20
            out.update(sweeps=int(sweeps), descent=int(descent or 0), active_share=edges_share(disc.dim), message=lb.message, time_s=time.perf_counter() - t1, lower=lb.lower, upper=up.Pi, upper_certified=up.certified,
                       certified=lb.certified, certificate_worst=lb.certificate.worst, timings=lb.timings)
    out["peak_rss_mb"] = peak_memory() / 2**20
    return out


def edges_share(dim: int) -> float:
    from elastoplast.bounds.local import sweeps

    return float(sweeps.ACTIVE_SHARE[dim])


def report(results: dict) -> str:
    lines = ["Each run in its own process; seconds (wall clock); `local MB` is the peak of the process that ran the",
             "newton solve, the upper bound and the local bound (`newton MB` the solve alone).", "",
             "`sweeps` is S sweeps, S+D with at most D descent steps after them, @A the revisit share (sweeps.ACTIVE_SHARE) where",
             "it is not the package's (3D: 1.0; 0.05 before), u: the upper bound given (the descent then also stops once it",
             "gains little against the gap, as `bounds` and `adapt` run it).",
             "`s/sweep` is the sweeps' time over their number (at most that many: after the first, a sweep visits only the",
             "rings next to a ring that moved), `rings s` the ring set-up (edge patches in 3D, vertex stars in 2D: topology,",
             "colours, boundary-ring bases), `descent s (steps)` the descent over all rings after the sweeps and the steps it",
             "took (at most D of `S+D`), `repair s` the round-off repair after them (ring passes, nothing global).",
             "`ratio` is local s over newton s.", "",
             "| problem | elements | sweeps | newton s | local s | ratio | s/sweep | rings s | descent s (steps) | repair s | global s | newton MB | "
             "local MB | global MB | upper | local lower | global lower | gap ratio | local certified | worst residual |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["cases"]:
        g, nw = r.get("global", {}), r.get("newton", {})
        for key, lo in r.items():
            if not key.startswith("local-"):
                continue
            if "lower" not in lo:
                lines.append(f"| {r['problem']} | {r['divisions']} | {key} | error: {lo.get('error', '')} |")
                continue
            gl = g.get("lower", float("nan"))
            ratio = (lo["upper"] - lo["lower"]) / (lo["upper"] - gl) if "lower" in g else float("nan")
            lines.append(
                f"| {r['problem']} | {lo['n_elements']} | {key.split('-')[1]} | {nw.get('newton_s', float('nan')):.2f} | "
                f"{lo['time_s']:.2f} | {lo['time_s'] / nw.get('newton_s', float('nan')):.1f} | {_per_sweep(lo)} | "
                f"{lo['timings'].get('rings', 0.0):.2f} | {_descent(lo)} | "
                f"{lo['timings'].get('repair', 0.0):.2f} | {g.get('time_s', float('nan')):.2f} | {nw.get('peak_rss_mb', float('nan')):.0f} | "
                f"{lo['peak_rss_mb']:.0f} | {g.get('peak_rss_mb', float('nan')):.0f} | {lo['upper']:.6g} | "
                f"{lo['lower']:.6g} | {gl:.6g} | {ratio:.2f} | {lo['certified']} | {lo['certificate_worst']:.1e} |")
    return "\n".join(lines) + "\n"


def _descent(lo: dict) -> str:
    t = lo["timings"]
    return f"{t['descent']:.2f} ({t.get('descent_steps', 0)})" if "descent" in t else "-"


def _per_sweep(lo: dict) -> str:
    n = int(lo.get("sweeps", 0) or 0)
    return f"{lo['timings']['sweeps'] / n:.3f}" if n and "sweeps" in lo["timings"] else "-"


def measure(mode: str, out: Path) -> dict:
    results = {"cases": []}
    for problem, sizes in (QUICK if mode == "quick" else CASES).items():
        for div in sizes:
            case = {"problem": problem, "divisions": list(div)}
            case["newton"] = run_child(__file__, [problem, list(div), "newton"], cwd=ROOT)
            if (problem, tuple(div)) not in NO_GLOBAL:
                case["global"] = run_child(__file__, [problem, list(div), "global"], cwd=ROOT)
            for v in VARIANTS[problem]:
                case[f"local-{v}"] = run_child(__file__, [problem, list(div), f"local-{v}"], cwd=ROOT)
            results["cases"].append(case)
            print(json.dumps(case), flush=True)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "the cylinder at 576 triangles", HERE, TITLE, "local lower-bound study", measure,
                      report, argv=argv, study=STUDY, child=lambda spec: run_one(*spec))


if __name__ == "__main__":
    sys.exit(main())
