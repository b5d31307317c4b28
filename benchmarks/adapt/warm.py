"""Side study: what warm starts save in the adaptive loop (issue 11).

    python benchmarks/adapt/warm.py [--quick] [--out DIR] [--report]

The adaptive loop of ``run.py`` (2D cylinder from 20 x 10 divisions, θ = 0.5) up to
about 12,000 triangles, then on each of its meshes after the first, interleaved in
one process so that the machine's load hits both alike: Newton from zero (cold)
and Newton from the previous mesh's solution interpolated onto the new nodes
(warm, ``prolong_p1`` with the refinement's own state, as the loop does), for the
problem and for its conservative variant (the two P1 solves of a step). Each
solve is repeated ``REPEATS`` times and the fastest kept. Also: the lower bound's
time on the same mesh, to put the solves in proportion.

Writes ``warm.json`` and ``warm.md`` beside this file (``--quick``: into quick/).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import elastoplast as ep
import elastoplast.adapt.budget as budget
from elastoplast.adapt.records import AdaptOptions
from elastoplast.adapt.loop import adapt
from elastoplast.mesh.refinement import refine
from elastoplast.bounds.upper import conservative_discretization
from elastoplast.bounds.equilibrium.bound import solve_lower_bound
from elastoplast.solvers.newton import NewtonOptions, solve_newton
from elastoplast.problem.definition import read_toml
from elastoplast.mesh.refinement import prolong_p1

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TITLE = "Warm starts in the adaptive loop (side study)"
SETTINGS = {"full": {"divisions": [20, 10], "max_elements": 12_000}, "quick": {"divisions": [10, 5], "max_elements": 800}}
REPEATS = 3


def fastest(fn) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def measure(mode: str) -> dict:
    data = read_toml(ROOT / "problems" / "cylinder_2d.toml")
    data["mesh"]["divisions"] = SETTINGS[mode]["divisions"]
    problem = ep.problem_from_dict(data)
    states = {}

    def keep_state(mesh, marked, state=None, **kw):  # the loop's own refinement, its states kept
        new, st, parent = refine(mesh, marked, state, **kw)
        states[id(new)] = st
        return new, st, parent

    budget.refine = keep_state  # the refinement step of the loop (elastoplast.adapt.budget)
    try:
        run = adapt(problem, AdaptOptions(rtol=1e-6, bracket="never", max_elements=SETTINGS[mode]["max_elements"]))
    finally:
        budget.refine = refine
    opts = NewtonOptions(tol=AdaptOptions().tol)
    rows = []
    previous = None
    for mesh in run.meshes:
        disc = ep.discretize(replace(problem, mesh=mesh))
        cdisc = conservative_discretization(disc)
        row = {"elements": disc.n_elements}
        sols = {}
        for name, d in (("problem", disc), ("conservative", cdisc)):
            t_cold, cold = fastest(lambda: solve_newton(d, opts))
            row[f"{name}_cold_s"], row[f"{name}_cold_it"] = t_cold, cold.iterations
            if previous is not None:
                start = replace(previous[name], u=prolong_p1(states[id(mesh)], previous[name].u))
                t_warm, warm = fastest(lambda: solve_newton(d, opts, warm_start=start))
                row[f"{name}_warm_s"], row[f"{name}_warm_it"] = t_warm, warm.iterations
                row[f"{name}_dU"] = abs(warm.U - cold.U) / abs(cold.U)
            sols[name] = cold
        t0 = time.perf_counter()
        solve_lower_bound(disc)
        row["lower_s"] = time.perf_counter() - t0
        print(row, flush=True)
        rows.append(row)
        previous = sols
    return {"mode": mode, "divisions": SETTINGS[mode]["divisions"], "repeats": REPEATS, "tol": opts.tol,
            "rows": rows}


def report(res: dict) -> str:
    rows = [r for r in res["rows"] if "problem_warm_s" in r]
    body = [f"2D cylinder from {res['divisions']} divisions, θ = 0.5; Newton to KKT tol {res['tol']:g}; fastest of "
            f"{res['repeats']} runs each, cold and warm interleaved on the same mesh. `dU`: relative difference of "
            "U between the warm and the cold answer (the discrete solution is unique for H > 0).", "",
            "| elements | it. cold | it. warm | s cold | s warm | conservative: it. cold | it. warm | s cold | s warm | "
            "max dU | lower bound s |", "|" + "---|" * 11]
    for r in rows:
        body.append(f"| {r['elements']:,} | {r['problem_cold_it']} | {r['problem_warm_it']} | {r['problem_cold_s']:.3f} | "
                    f"{r['problem_warm_s']:.3f} | {r['conservative_cold_it']} | {r['conservative_warm_it']} | "
                    f"{r['conservative_cold_s']:.3f} | {r['conservative_warm_s']:.3f} | "
                    f"{max(r['problem_dU'], r['conservative_dU']):.1e} | {r['lower_s']:.2f} |")
    cold = sum(r["problem_cold_s"] + r["conservative_cold_s"] for r in rows)
    warm = sum(r["problem_warm_s"] + r["conservative_warm_s"] for r in rows)
    lower = sum(r["lower_s"] for r in rows)
    it_c = sum(r["problem_cold_it"] + r["conservative_cold_it"] for r in rows)
    it_w = sum(r["problem_warm_it"] + r["conservative_warm_it"] for r in rows)
    body += ["", f"Over these meshes: Newton iterations {it_c} cold, {it_w} warm ({it_w / it_c:.2f}x); solve time "
             f"{cold:.1f} s cold, {warm:.1f} s warm ({warm / cold:.2f}x), saving {cold - warm:.1f} s against "
             f"{lower:.1f} s of lower bounds on the same meshes ({(cold - warm) / (cold + lower):.1%} of "
             "solves plus lower bounds)."]
    return "\n".join(body)


def main(argv=None) -> int:
    return run_record(__doc__, "a coarse start up to 800 triangles", HERE, TITLE, "warm-start study",
                      lambda mode, out: measure(mode), report, argv=argv, study="warm")


if __name__ == "__main__":
    sys.exit(main())
