"""Side study: cost of the certified lower bound (equilibrium element) against the (S) conic solve.

    python benchmarks/bounds/lower.py [--quick] [--out DIR] [--report] [--skip-qdldl-from N]

On the 2D cylinder (problems/cylinder_2d.toml, graded) and the 3D quarter sphere
(problems/sphere_quarter_3d.toml, two symmetry planes) at a few sizes, each solve runs
in its own process so that its peak memory (VmHWM) is its own: ``ep.solve(disc,
"conic")`` (value_D = Pi at the P1 solution) and ``solve_lower_bound`` (the bound
-J <= Pi*, its certificate, the phases' timings). 3D cases also run the lower bound
with Clarabel's faer factorisation. Writes ``lower.json`` and ``lower.md`` beside this
file (or into ``--out``; ``--quick`` writes into ``benchmarks/bounds/quick/``);
``--report`` renders ``lower.md`` again from ``lower.json``.
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
STUDY = "lower"
TITLE = "Lower bound (equilibrium element) against the (S) conic solve"

CASES = {
    "cylinder_2d": [(24, 12), (40, 20), (80, 40), (120, 60)],
    "sphere_quarter_3d": [(3, 3, 3), (4, 4, 3), (5, 5, 4), (6, 6, 5)],
}
QUICK = {"cylinder_2d": [(24, 12), (40, 20)], "sphere_quarter_3d": [(3, 3, 3)]}


def run_one(problem: str, divisions, what: str) -> dict:
    """One solve in this process: ``what`` is 'conic' or 'lower-<linear solver>'."""
    import elastoplast as ep
    from elastoplast.bounds.lower import LowerBoundOptions
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound

    disc = shipped_problem(problem, divisions)
    out = {"n_elements": int(disc.n_elements)}
    t0 = time.perf_counter()
    if what == "conic":
        sol = ep.solve(disc, "conic")
        out.update(time_s=time.perf_counter() - t0, value_D=sol.value_D, status=sol.status.value,
                   kkt_worst=sol.kkt.worst)
    else:
        lb = solve_lower_bound(disc, LowerBoundOptions(linear_solver=what.split("-", 1)[1]))
        out.update(time_s=time.perf_counter() - t0, lower=-lb.J, J_solver=lb.J_solver, certified=lb.certified,
                   certificate_worst=lb.certificate.worst, repair_residual=lb.repair_residual,
                   iterations=lb.iterations, timings=lb.timings, status=lb.status.value, message=lb.message)
    out["peak_rss_mb"] = peak_memory() / 2**20
    return out


def spawn(problem: str, divisions, what: str) -> dict:
    """:func:`run_one` in its own process."""
    return run_child(__file__, [problem, list(divisions), what], cwd=ROOT)


def report(results: dict) -> str:
    lines = [
        "Each solve in its own process; times in seconds (wall clock, whole call), peak RSS of that process.",
        "`gap` = (value_D - lower) / |value_D|: value_D = Pi(u_h, U_h) >= -J (weak duality with the P1",
        "interpolant of psi, see tests/test_equilibrium.py), so it is >= 0; it is the bracket on Pi* only",
        "where value_D is itself an upper bound on Pi* (flat psi), otherwise the upper-bound helper's corrected",
        "value takes its place.", "",
        "| problem | elements | conic s | lower s (qdldl) | ratio | lower s (faer) | conic MB | lower MB | "
        "lower = -J | value_D | gap | certified | worst residual | repair residual |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["cases"]:
        c, lq, lf = r["conic"], r.get("lower-qdldl", {}), r.get("lower-faer", {})
        low = lq if "lower" in lq else lf
        if "error" in c or "lower" not in low:
            lines.append(f"| {r['problem']} | {r['divisions']} | error: {c.get('error', '')} {lq.get('error', '')} {lf.get('error', '')} |")
            continue
        gap = (c["value_D"] - low["lower"]) / abs(c["value_D"])
        tq = f"{lq['time_s']:.2f}" if "time_s" in lq else "-"
        tf = f"{lf['time_s']:.2f}" if "time_s" in lf else "-"
        ratio = f"{lq['time_s'] / c['time_s']:.0f}" if "time_s" in lq else "-"
        lines.append(
            f"| {r['problem']} | {c['n_elements']} | {c['time_s']:.2f} | {tq} | {ratio} | {tf} | {c['peak_rss_mb']:.0f} | "
            f"{low['peak_rss_mb']:.0f} | {low['lower']:.6g} | {c['value_D']:.6g} | {gap:.2e} | {low['certified']} | "
            f"{low['certificate_worst']:.1e} | {low['repair_residual']:.1e} |")
    lines += ["", "Phases of the lower bound (qdldl where run, else faer), seconds:", "",
              "| problem | elements | setup | assemble | solve | repair | certify | Clarabel iterations |",
              "|---|---|---|---|---|---|---|---|"]
    for r in results["cases"]:
        low = r.get("lower-qdldl", {}) if "timings" in r.get("lower-qdldl", {}) else r.get("lower-faer", {})
        if "timings" not in low:
            continue
        t = low["timings"]
        lines.append(f"| {r['problem']} | {low['n_elements']} | {t.get('setup', 0):.2f} | {t.get('assemble', 0):.2f} | "
                     f"{t.get('solve', 0):.2f} | {t.get('repair', 0):.2f} | {t.get('certify', 0):.2f} | {low['iterations']} |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path, skip_qdldl_from: int) -> dict:
    results = {"cases": []}
    for problem, sizes in (QUICK if mode == "quick" else CASES).items():
        for div in sizes:
            case = {"problem": problem, "divisions": list(div), "conic": spawn(problem, div, "conic")}
            n = case["conic"].get("n_elements", 0)
            if problem.endswith("2d") or n < skip_qdldl_from:
                case["lower-qdldl"] = spawn(problem, div, "lower-qdldl")
            if problem.endswith("3d"):
                case["lower-faer"] = spawn(problem, div, "lower-faer")
            results["cases"].append(case)
            print(json.dumps(case), flush=True)
    return results


def main(argv=None) -> int:
    skip = {"type": int, "default": 1000,
            "help": "3D: run the lower bound with qdldl only below this many elements (it is 2-3x slower than faer)"}
    return run_record(__doc__, "the cylinder at 576 and 1,600 triangles, the 3D quarter at 3 x 3 x 3", HERE, TITLE,
                      "lower-bound study", measure, report, argv=argv, study=STUDY,
                      child=lambda spec: run_one(*spec), options={"--skip-qdldl-from": skip})


if __name__ == "__main__":
    sys.exit(main())
