"""Adaptive against uniform refinement, driven by the certified gap (issue 11).

    python benchmarks/adapt/run.py [--quick] [--out DIR] [--report]

Two problems, each from a coarse graded mesh of its problem file:

* ``cylinder_2d`` (problems/cylinder_2d.toml, 20 x 10 divisions, 400 triangles):
  the adaptive loop (``elastoplast.adapt.loop.adapt``) to rtol = 1e-3 with θ = 0.3, 0.5
  and 0.7; uniform refinement (``uniform``: every triangle into four) from the
  same mesh up to the finest mesh the lower bound accepts (25,600 triangles; the
  next, 102,400, is above its limit); θ = 0.5 again without warm starts (Newton
  from zero on every mesh) up to 7,000 triangles, to measure what the warm start
  saves; θ = 0.5 with the U bracket at every step to rtol = 1e-2, to measure its
  cost and check that the brackets of all meshes intersect.
* ``sphere_quarter_3d`` (problems/sphere_quarter_3d.toml, 4 x 4 x 4 divisions, 384
  tetrahedra): the adaptive loop with θ = 0.5, rtol = 1e-3 and a time limit of 600 s
  (the issue's ten minutes, U bracket on the final mesh included); uniform
  refinement from the same mesh (384, 3,072, 24,576: the finest the lower bound
  accepts, LOWER_BOUND_MAX_ELEMENTS = 25,000 in 3D with SCS, its solver there
  from 500 tetrahedra; the next, 196,608, is far above it).

Derived: fitted exponents p of gap ~ N^-p (all steps, and the last four), the
element ratio at equal gap (the finest uniform mesh's gap against the adaptive
sequence, log-log interpolated), the time to rtol per θ, the Newton iterations and
solve time warm against cold, the U bracket's cost against the lower bound at F.
Plots: ``gap.png`` (gap against elements, both problems) and, from the run itself
(not from the JSON), ``indicator_2d.png`` and ``indicator_3d.png``: the final
adapted meshes coloured by the marking indicator (3D: the section by the symmetry
plane y = 0).

``--quick``: coarser starts, loose targets, about a minute, into quick/.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import elastoplast as ep
from elastoplast.adapt.records import AdaptOptions, Step, elements_at_gap, fitted_rate
from elastoplast.adapt.loop import adapt, uniform
from elastoplast.plots.figures import plot_gap_curves, plot_indicator
from elastoplast.problem.definition import read_toml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TITLE = "Adaptive refinement driven by the certified gap (issue 11)"

CASES = {
    "full": {
        "2d": {"problem": "cylinder_2d", "divisions": [20, 10], "rtol": 1e-3, "thetas": [0.3, 0.5, 0.7],
               "uniform_max": 25_600, "cold_max": 7_000, "every_rtol": 1e-2, "time_limit": None},
        "3d": {"problem": "sphere_quarter_3d", "divisions": [4, 4, 4], "rtol": 1e-3, "thetas": [0.5],
               "uniform_max": 24_576, "cold_max": None, "every_rtol": None, "time_limit": 600.0},
    },
    "quick": {
        "2d": {"problem": "cylinder_2d", "divisions": [10, 5], "rtol": 2e-2, "thetas": [0.3, 0.5, 0.7],
               "uniform_max": 1_600, "cold_max": 600, "every_rtol": 5e-2, "time_limit": None},
        "3d": {"problem": "sphere_quarter_3d", "divisions": [3, 3, 3], "rtol": 1e-3, "thetas": [0.5],
               "uniform_max": 162, "cold_max": None, "every_rtol": None, "time_limit": 20.0},
    },
}
#: the steps the "asymptotic" exponent is fitted over
TAIL = 4


def problem_of(case: dict) -> ep.Problem:
    data = read_toml(ROOT / "problems" / f"{case['problem']}.toml")
    data["mesh"]["divisions"] = list(case["divisions"])
    return ep.problem_from_dict(data)


def log(step: Step) -> None:
    print(f"  {step.line()}  [solve {step.solve_seconds:.1f} s, {step.iterations} it; lower {step.lower_seconds:.1f} s"
          + (f"; bracket {step.bracket_seconds:.1f} s" if step.bracket_seconds else "") + "]", flush=True)


def record_run(name: str, run, seconds: float, options: AdaptOptions) -> dict:
    return {"name": name, "reason": run.reason, "seconds": seconds, "options": options.persistent(),
            "warm_start": options.warm_start, "steps": [s.as_dict() for s in run.steps]}


def timed(name: str, fn, problem, options, **kw) -> tuple[dict, object]:
    print(f"{name}:", flush=True)
    t0 = time.perf_counter()
    run = fn(problem, options, report=log, **kw)
    seconds = time.perf_counter() - t0
    print(f"  -> {run.reason} ({seconds:.0f} s)", flush=True)
    return record_run(name, run, seconds, options), run


def run_case(key: str, case: dict, out: Path) -> dict:
    problem = problem_of(case)
    base = AdaptOptions(rtol=case["rtol"], time_limit=case["time_limit"])
    runs = {}
    final = None
    for theta in case["thetas"]:
        # the U bracket (two more lower bounds on the final mesh) only where it is reported: θ = 0.5
        rec, run = timed(f"adaptive, theta = {theta}", adapt, problem,
                         replace(base, theta=theta, bracket="final" if theta == 0.5 else "never"))
        runs[f"adaptive {theta}"] = rec
        if theta == 0.5:
            final = run
    rec, _ = timed("uniform", uniform, problem, base, max_elements=case["uniform_max"])
    runs["uniform"] = rec
    if case["cold_max"]:
        rec, _ = timed("adaptive, theta = 0.5, no warm start", adapt, problem,
                       replace(base, max_elements=case["cold_max"], warm_start=False))
        runs["cold 0.5"] = rec
    if case["every_rtol"]:
        rec, _ = timed("adaptive, theta = 0.5, U bracket at every step", adapt, problem,
                       replace(base, rtol=case["every_rtol"], bracket="every"))
        runs["every 0.5"] = rec
    axis = {} if problem.dim == 2 else {"axis": 1, "value": 0.0}
    plot_indicator(out / f"indicator_{key}.png", final.disc, final.solution, final.bounds, **axis,
                   title=f"{case['problem']}: the final adaptive mesh (θ = 0.5), coloured by the marking indicator")
    return {"problem": case["problem"], "dim": problem.dim, "divisions": case["divisions"], "rtol": case["rtol"],
            "time_limit": case["time_limit"], "initial_elements": problem.mesh.n_elements, "runs": runs}


# ----------------------------------------------------------------------------
# derived figures
# ----------------------------------------------------------------------------


def steps_of(rec: dict) -> list[Step]:
    return [Step(**s) for s in rec["steps"]]


def derived(case: dict) -> dict:
    runs = case["runs"]
    uni = steps_of(runs["uniform"])
    out = {"uniform_rate": fitted_rate(uni), "finest_uniform_elements": uni[-1].n_elements,
           "finest_uniform_gap": uni[-1].gap_rel, "adaptive": {}}
    for name, rec in runs.items():
        if not name.startswith("adaptive"):
            continue
        st = steps_of(rec)
        n_eq = elements_at_gap(st, uni[-1].gap_rel)
        reached = [s for s in st if s.gap_rel <= case["rtol"]]
        out["adaptive"][name] = {
            "rate_all": fitted_rate(st), "rate_tail": fitted_rate(st, TAIL),
            "elements_at_finest_uniform_gap": n_eq, "element_ratio": uni[-1].n_elements / n_eq if n_eq else math.nan,
            "steps": len(st), "final_elements": st[-1].n_elements, "final_gap": st[-1].gap_rel,
            "seconds": rec["seconds"], "reached_rtol": bool(reached),
            "seconds_to_rtol": sum(s.seconds - s.bracket_seconds for s in st[:st.index(reached[0]) + 1]) if reached
            else math.nan,
            "lower_seconds": sum(s.lower_seconds for s in st), "solve_seconds": sum(s.solve_seconds for s in st),
            "bracket_seconds": sum(s.bracket_seconds for s in st),
            "other_seconds": rec["seconds"] - sum(s.solve_seconds + s.lower_seconds + s.bracket_seconds for s in st),
            "U_lower": st[-1].U_lower, "U_upper": st[-1].U_upper, "U_h": st[-1].U,
            "certified": all(s.certified for s in st)}
    if "cold 0.5" in runs:
        warm, cold = steps_of(runs["adaptive 0.5"]), steps_of(runs["cold 0.5"])
        common = [(w, c) for w, c in zip(warm, cold) if w.n_elements == c.n_elements]
        out["warm_start"] = {
            "rows": [{"elements": w.n_elements, "iterations_warm": w.iterations, "iterations_cold": c.iterations,
                      "solve_warm": w.solve_seconds, "solve_cold": c.solve_seconds,
                      "step_warm": w.solve_seconds + w.lower_seconds, "step_cold": c.solve_seconds + c.lower_seconds}
                     for w, c in common[1:]],  # the first mesh starts cold in both
            "same_meshes": len(common) == min(len(warm), len(cold))}
    if "every 0.5" in runs:
        ev = steps_of(runs["every 0.5"])
        out["every_bracket"] = {
            "steps": len(ev), "seconds": runs["every 0.5"]["seconds"],
            "lower_seconds": sum(s.lower_seconds for s in ev), "bracket_seconds": sum(s.bracket_seconds for s in ev),
            "U_lower_max": max(s.U_lower for s in ev), "U_upper_min": min(s.U_upper for s in ev),
            "energy_lower_max": max(s.energy_lower for s in ev), "energy_upper_min": min(s.energy_upper for s in ev),
            "rows": [{"elements": s.n_elements, "U_lower": s.U_lower, "U_upper": s.U_upper, "U_h": s.U,
                      "width_over_U": (s.U_upper - s.U_lower) / s.U} for s in ev]}
    return out


def run_all(mode: str, out: Path) -> dict:
    res = {"mode": mode, "cases": {}}
    for key, case in CASES[mode].items():
        print(f"== {key}: {case['problem']} ==", flush=True)
        res["cases"][key] = run_case(key, case, out)
        res["cases"][key]["derived"] = derived(res["cases"][key])
    res["peak_rss_mb"] = peak_memory() / 2**20
    return res


# ----------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------


def table(head: list[str], rows: list[list]) -> str:
    return "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
                     + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def fmt(x, spec=".3g") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def steps_table(rec: dict) -> str:
    rows = [[s["step"], f"{s['n_elements']:,}", f"{s['energy_lower']:.8g}", f"{s['energy_upper']:.8g}",
             f"{s['gap_rel']:.3e}", fmt(s["U_lower"], ".5g"), fmt(s["U_upper"], ".5g"), fmt(s["theta"], ".3f"),
             s["marked"], s["iterations"], f"{s['solve_seconds']:.1f}", f"{s['lower_seconds']:.1f}",
             f"{s['bracket_seconds']:.1f}", f"{s['seconds']:.1f}", "yes" if s["certified"] else "NO"]
            for s in rec["steps"]]
    return table(["step", "elements", "lower", "upper", "rel. gap", "U lower", "U upper", "θ used", "marked",
                  "Newton it.", "solve s", "lower s", "bracket s", "step s", "certified"], rows)


def report(res: dict) -> str:
    L = [f"Mode: {res['mode']}. Peak memory of the run {res['peak_rss_mb']:.0f} MB. Every step below is certified "
         "unless its last column says NO. Times are wall-clock on a shared two-core machine (other jobs ran "
         "alongside): compare ratios within one run.", ""]
    for key, case in res["cases"].items():
        dv = derived(case)  # from the recorded steps (the same as case["derived"] of the run)
        L += [f"## {case['dim']}D: {case['problem']} (from {case['initial_elements']:,} elements, "
              f"divisions {case['divisions']})", ""]
        rows = []
        for name, a in dv["adaptive"].items():
            rows.append([name, a["steps"], f"{a['final_elements']:,}", f"{a['final_gap']:.3e}",
                         "yes" if a["reached_rtol"] else "no", f"{a['rate_all']:.2f}", f"{a['rate_tail']:.2f}",
                         fmt(a["elements_at_finest_uniform_gap"], ",.0f"), fmt(a["element_ratio"], ".1f"),
                         f"{a['seconds']:.0f}", fmt(a["seconds_to_rtol"], ".0f"), f"{a['lower_seconds']:.0f}",
                         f"{a['solve_seconds']:.0f}", f"{a['bracket_seconds']:.0f}", f"{a['other_seconds']:.0f}", fmt(a["U_lower"], ".5g"), fmt(a["U_upper"], ".5g")])
        L += [f"Target rtol = {case['rtol']:g}" + (f", time limit {case['time_limit']:g} s" if case["time_limit"] else "")
              + f". Uniform refinement: fitted exponent p = {dv['uniform_rate']:.2f}; its finest mesh "
              f"({dv['finest_uniform_elements']:,} elements) has the gap {dv['finest_uniform_gap']:.3e}. "
              f"`elements at that gap`: where the adaptive sequence reaches it (log-log interpolation); `ratio`: "
              f"{dv['finest_uniform_elements']:,} over it. `p all`/`p last {TAIL}`: fitted exponent of gap ~ N^-p "
              "over all steps / the last ones.", "",
              table(["run", "steps", "final elements", "final gap", "rtol reached", "p all", f"p last {TAIL}",
                     "elements at finest uniform gap", "ratio", "total s", "s to rtol", "lower-bound s", "solve s",
                     "bracket s", "other s", "U lower", "U upper"], rows), "",
              "`s to rtol`: the steps up to the first mesh at rtol, without the U bracket (computed on the final "
              "mesh for θ = 0.5 only); `total s` includes it. `lower-bound s`: the lower-bound programs at F; "
              "`solve s`: discretisation, the P1 solves (the problem and its conservative variant) and "
              "their upper bounds; `bracket s`: the U bracket's two programs at F ∓ δ; `other s`: the rest of "
              "`total s` (marking, refinement, interpolation of the warm starts).", ""]
        if case["time_limit"]:
            a = dv["adaptive"]["adaptive 0.5"]
            miss = a["final_gap"] / case["rtol"]
            L += [f"**Budget of {case['time_limit']:g} s**: the run took {a['seconds']:.0f} s in all (U bracket "
                  f"included) and ended with {a['final_elements']:,} elements, relative gap {a['final_gap']:.3e}, "
                  f"U in [{a['U_lower']:.5g}, {a['U_upper']:.5g}] (discrete U_h = {a['U_h']:.5g}; width "
                  f"{(a['U_upper'] - a['U_lower']) / a['U_h']:.2f} U_h), certified: {a['certified']}. Time split: "
                  f"lower bounds at F {a['lower_seconds']:.0f} s, U bracket {a['bracket_seconds']:.0f} s, P1 solves and "
                  f"upper bounds {a['solve_seconds']:.0f} s, the rest {a['other_seconds']:.0f} s. "
                  + ("The target rtol was reached." if a["reached_rtol"] else
                     f"The target rtol = {case['rtol']:g} was missed by a factor {miss:.0f} in the gap. At the "
                     f"asymptotic rate of P1 elements, gap ~ N^(-2/d) (the gap bounds the squared energy error, "
                     f"optimal at N^(-1/d) for adaptive P1), reaching it would take about "
                     f"{a['final_elements'] * miss ** (case['dim'] / 2):,.0f} elements; at the steeper fitted "
                     f"rate of the last steps (p = {a['rate_tail']:.2f}, still pre-asymptotic) about "
                     f"{a['final_elements'] * miss ** (1 / a['rate_tail']):,.0f}."), ""]
        if "warm_start" in dv:
            ws = dv["warm_start"]
            rw = [[f"{r['elements']:,}", r["iterations_cold"], r["iterations_warm"], f"{r['step_cold']:.1f}",
                   f"{r['step_warm']:.1f}"] for r in ws["rows"]]
            ic, iw = sum(r["iterations_cold"] for r in ws["rows"]), sum(r["iterations_warm"] for r in ws["rows"])
            L += ["### Warm starts", "",
                  "The same meshes (the same in both runs: "
                  f"{ws['same_meshes']}) solved by Newton from zero (cold) and from the previous mesh's solution "
                  f"interpolated (warm): {ic} Newton iterations cold, {iw} warm ({fmt(iw / ic if ic else math.nan, '.2f')}x) "
                  "for the problem's solves. The two runs' times are not comparable: the machine's load changed between "
                  "them (`solve + lower s`: the same lower-bound programs took up to twice as long in one run as in the "
                  "other); `warm.md` measures the solve times interleaved on the same meshes.", "",
                  table(["elements", "Newton it. cold", "warm", "solve + lower s, cold run", "warm run"], rw), ""]
        if "every_bracket" in dv:
            eb = dv["every_bracket"]
            re_ = [[f"{r['elements']:,}", f"{r['U_lower']:.5g}", f"{r['U_upper']:.5g}", f"{r['U_h']:.5g}",
                    f"{r['width_over_U']:.3f}"] for r in eb["rows"]]
            L += ["### The U bracket at every step", "",
                  f"θ = 0.5 with `bracket = \"every\"` to rtol = {case['runs']['every 0.5']['options']['rtol']:g}: "
                  f"{eb['steps']} meshes in {eb['seconds']:.0f} s: the lower bounds at F took {eb['lower_seconds']:.0f} s, "
                  f"the brackets' lower bounds at F - δ and F + δ {eb['bracket_seconds']:.0f} s "
                  f"({fmt(eb['bracket_seconds'] / eb['lower_seconds'], '.2f')}x as long). All brackets hold together: "
                  f"max U_lower = {eb['U_lower_max']:.5g} <= min U_upper = {eb['U_upper_min']:.5g}; "
                  f"max lower = {eb['energy_lower_max']:.8g} <= min upper = {eb['energy_upper_min']:.8g}.", "",
                  table(["elements", "U lower", "U upper", "U_h", "width / U_h"], re_), ""]
        for name, rec in case["runs"].items():
            L += [f"### {name}", "", f"Stopped: {rec['reason']} ({rec['seconds']:.0f} s).", "", steps_table(rec), ""]
    L += ["## Figures", "", "![gap](gap.png)", ""]
    L += [f"![indicator {k}](indicator_{k}.png)" for k in res["cases"]] + [""]
    return "\n".join(L)


def plots(res: dict, out: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 4.6), layout="constrained")
    axes = fig.subplots(1, len(res["cases"]))
    for ax, (key, case) in zip(np.atleast_1d(axes), res["cases"].items()):
        curves = {name.replace("adaptive", "adaptive θ =") if name.startswith("adaptive") else name: steps_of(rec)
                  for name, rec in case["runs"].items() if name.startswith("adaptive") or name == "uniform"}
        plot_gap_curves(ax, curves)
        ax.axhline(case["rtol"], color="k", ls=":", lw=0.8)
        ax.set_title(f"{case['dim']}D {case['problem']}" + (f" ({case['time_limit']:g} s budget)" if case["time_limit"] else ""))
    fig.savefig(out / "gap.png", dpi=120)


def main(argv=None) -> int:
    return run_record(__doc__, "coarse starts and loose targets (about a minute)", HERE, TITLE, "adapt benchmark", run_all, report, plots, argv)


if __name__ == "__main__":
    sys.exit(main())
