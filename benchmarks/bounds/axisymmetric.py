"""Side study: certified bounds on axisymmetric indentation (the meridian plane).

    python benchmarks/bounds/axisymmetric.py [--quick] [--out DIR] [--report]

On problems/sphere_axisymmetric.toml (a sphere pressed into a steel cylinder, plastic
zone well developed) and a more plastic variant (the same problem at 4 F), for a few
divisions of its graded rectangle: the P1 solve (newton), the certified bracket of
``certified_bounds`` (the upper bound by the vertex rule, the global lower bound in
``tau = r sigma``, the U bracket from two more lower bounds) and the phases' times; then
``elastoplast adapt``'s loop (the global lower bound) to a relative gap of 1e-3 from the
coarsest mesh, its steps and times. Each case runs in its own process. Writes
``axisymmetric.json`` and ``axisymmetric.md`` beside this file (``--quick``: into
``quick/``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STUDY = "axisymmetric"
TITLE = "Certified bounds on axisymmetric sphere indentation"

VARIANTS = {"sphere_axisymmetric": 1.0, "sphere_axisymmetric_4F": 4.0}
DIVISIONS = [15, 30, 60]
QUICK = [10, 20]
ADAPT_RTOL = 1e-3
ADAPT_TIME = 900.0


def problem(variant: str, n: int):
    import elastoplast as ep

    data = ep.read_toml(ROOT / "problems" / "sphere_axisymmetric.toml")
    data["mesh"]["divisions"] = [n, n]
    data["load"]["force"] = float(data["load"]["force"]) * VARIANTS[variant]
    return ep.problem_from_dict(data, base_dir=ROOT / "problems")


def run_one(spec) -> dict:
    """One case in this process: ``[variant, n, "bounds" | "adapt"]``."""
    import elastoplast as ep
    from elastoplast.references.certified import certified_bounds

    variant, n, what = spec
    prob = problem(variant, n)
    if what == "adapt":
        t0 = time.perf_counter()
        run = ep.solve_adaptive(prob, ep.AdaptOptions(rtol=ADAPT_RTOL, time_limit=ADAPT_TIME, compare_uniform=False,
                                                      progress=False))
        steps = [{"n_elements": s.n_elements, "gap_rel": s.gap_rel, "lower": s.energy_lower, "upper": s.energy_upper,
                  "seconds": s.seconds, "certified": s.certified, "U_lower": s.U_lower, "U_upper": s.U_upper}
                 for s in run.steps]
        return {"time_s": time.perf_counter() - t0, "steps": steps, "reason": run.reason}
    disc = ep.discretize(prob)
    t0 = time.perf_counter()
    sol = ep.solve(disc, "newton", progress=False)
    t1 = time.perf_counter()
    rep = certified_bounds(disc, sol, "newton")
    b = rep.bounds
    plastic = float(disc.volumes[sol.plastic].sum() / disc.volumes.sum())
    return {"n_elements": int(disc.n_elements), "U_h": sol.U, "solve_s": t1 - t0, "timings": rep.timings,
            "lower": b.energy_lower, "upper": b.energy_upper, "gap_rel": b.energy_gap_rel,
            "stress_error_rel": b.stress_error_bound_rel, "U_lower": rep.U_lower, "U_upper": rep.U_upper,
            "certified": rep.certified, "certificate_worst": rep.lower.certificate.worst,
            "penetration": rep.upper.penetration, "plastic_volume_fraction": plastic}


def run(mode: str, out: Path) -> dict:
    sizes = QUICK if mode == "quick" else DIVISIONS
    cases = []
    for variant in VARIANTS:
        for n in sizes:
            r = run_child(__file__, [variant, n, "bounds"], cwd=ROOT)
            print(variant, n, r.get("gap_rel", r.get("error")), flush=True)
            cases.append({"variant": variant, "divisions": n, **r})
        if mode == "full":
            r = run_child(__file__, [variant, sizes[0], "adapt"], cwd=ROOT)
            print(variant, "adapt", r.get("time_s", r.get("error")), flush=True)
            cases.append({"variant": variant, "divisions": sizes[0], "adapt": r})
    return {"cases": cases}


def render(results: dict) -> str:
    lines = [
        "Each case in its own process, 2 shared cores; times in seconds (wall clock). `bounds` =",
        "`certified_bounds` on the P1 solution by newton: the upper bound (vertex rule on 8 x 8",
        "sub-triangles, with the solve of the conservative obstacle), the global lower bound in",
        "tau = r sigma, and the U bracket (two more lower bounds at F -/+ delta). `gap` is the certified",
        "relative energy gap, `stress err` the stress error bound relative to the energy norm.", "",
        "| problem | divisions | elements | solve s | upper s | lower s | U bracket s | lower | upper | gap | "
        "stress err | U_h | U bracket | plastic vol. | certified | certificate |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    adapt = []
    for c in results["cases"]:
        if "adapt" in c:
            adapt.append(c)
            continue
        if "error" in c:
            lines.append(f"| {c['variant']} | {c['divisions']} | error: {c['error']} |")
            continue
        t = c["timings"]
        lines.append(
            f"| {c['variant']} | {c['divisions']}² | {c['n_elements']:,} | {c['solve_s']:.1f} | {t['upper']:.1f} | "
            f"{t['lower']:.1f} | {t.get('bracket', float('nan')):.1f} | {c['lower']:.6f} | {c['upper']:.6f} | "
            f"{c['gap_rel']:.2e} | {c['stress_error_rel']:.2e} | {c['U_h']:.6g} | [{c['U_lower']:.6g}, "
            f"{c['U_upper']:.6g}] | {100 * c['plastic_volume_fraction']:.3g}% | {c['certified']} | "
            f"{c['certificate_worst']:.1e} |")
    for c in adapt:
        a = c["adapt"]
        lines += ["", f"## adapt, {c['variant']}, from {c['divisions']}² divisions, rtol {ADAPT_RTOL:g}", ""]
        if "error" in a:
            lines.append(f"error: {a['error']}")
            continue
        lines += [f"{a['reason']}; {a['time_s']:.1f} s in all.", "",
                  "| elements | lower | upper | gap | U bracket | step s | certified |", "|---|---|---|---|---|---|---|"]
        for s in a["steps"]:
            bracket = "" if s["U_lower"] != s["U_lower"] else f"[{s['U_lower']:.6g}, {s['U_upper']:.6g}]"
            lines.append(f"| {s['n_elements']:,} | {s['lower']:.6f} | {s['upper']:.6f} | {s['gap_rel']:.2e} | "
                         f"{bracket} | {s['seconds']:.1f} | {s['certified']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    return run_record(__doc__, "two small meshes, no adapt", HERE, TITLE, STUDY, run, render, argv=argv,
                      study=STUDY, child=run_one)


if __name__ == "__main__":
    raise SystemExit(main())
