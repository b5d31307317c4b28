"""Every method on the same problems in one run (issue 4).

    python benchmarks/methods/run.py            # full run (145 s wall in the recorded run, 2 cores)
    python benchmarks/methods/run.py --quick    # small meshes only (13 s wall), into quick/
    python benchmarks/methods/run.py --report   # only REPORT.md again, from results.json

Writes ``results.json`` and ``REPORT.md`` beside this file (``--out`` to
change). Per problem: each method's time, iterations, worst KKT residual, U
and its distance to a reference (the conic solution where it runs, otherwise
the method with the smallest KKT residual), and the time of one linear elastic
solve of the same mesh with the same factorisation (PARDISO: assembly of K,
symbolic analysis, numerical factorisation, one solve), the floor of issue 4's
first target. Targets, as ratios within this run:

* 3D sphere, >= 100k tetrahedra: fastest method to KKT <= 1e-8 within 10x the
  elastic solve;
* H = E/1000: fastest method >= 10x faster than plain Uzawa.

The cases with ``F*k`` multiply the problem's force by k: at the default loads
the plastic zones are small and plain Uzawa needs only 30-70 iterations even
at H = E/1000; the larger loads give the large plastic zones where its rate
degrades (issue 4's premise).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import elastoplast as ep
from elastoplast.certificate.kkt import energy_norm_sq
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.problem.definition import problem_from_dict, read_toml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
PROBLEMS = HERE.parents[1] / "problems"
TOL = 1e-8
#: tolerance of the Newton reference where the conic one is not run
REF_TOL = 1e-12


def case(name: str, divisions, hardening_over_E=None, force_factor=1.0):
    d = read_toml(PROBLEMS / f"{name}.toml")
    d["mesh"]["divisions"] = list(divisions)
    if hardening_over_E is not None:
        d["material"]["hardening"] = hardening_over_E * d["material"]["E"]
    d["load"]["force"] *= force_factor
    label = (f"{name} {'x'.join(map(str, divisions))}" + (f" H=E*{hardening_over_E:g}" if hardening_over_E else "")
             + (f" F*{force_factor:g}" if force_factor != 1.0 else ""))
    return label, ep.discretize(problem_from_dict(d, PROBLEMS))


def elastic_solve_time(disc) -> dict:
    """One linear elastic solve: K = B^T diag(|T| C) B, PARDISO analysis +
    factorisation + one solve (a unit load on the contact nodes)."""
    import pypardiso

    t0 = time.perf_counter()
    nd, _ = nondimensionalize(disc)
    C = nd.material.stiffness(nd.dim)
    K = sp.triu(nd.weighted_gram(C), format="csr")
    K.sort_indices()
    t1 = time.perf_counter()
    solver = pypardiso.PyPardisoSolver(mtype=2)
    b = nd.N.T @ np.full(nd.n_contact, nd.force / nd.n_contact)
    solver.factorize(K)
    t2 = time.perf_counter()
    solver.solve(K, b)
    t3 = time.perf_counter()
    solver.free_memory(everything=True)
    return {"assembly_s": t1 - t0, "factorization_s": t2 - t1, "solve_s": t3 - t2, "total_s": t3 - t0}


def run_method(disc, method: str, **opts) -> tuple[dict, ep.Solution]:
    t0 = time.perf_counter()
    sol = ep.solve(disc, method, **opts)
    wall = time.perf_counter() - t0
    row = {"method": method, "status": sol.status.value, "time_s": wall, "iterations": sol.iterations,
           "kkt_worst": sol.kkt.worst, "U": sol.U, "n_active": int(sol.active.sum()),
           "n_plastic": int(sol.plastic.sum()), "timings": sol.timings, "message": sol.message}
    if method == "newton":
        row["history_kkt"] = [h["kkt_worst"] for h in sol.history if "kkt_worst" in h]
        row["factorizations"] = int(sum(bool(h.get("factorized")) for h in sol.history))
        # the AMG-CG path (3D from NEWTON_AMG_FROM_ELEMENTS) builds hierarchies instead
        row["amg_setups"] = int(sum(bool(h.get("amg_setup")) for h in sol.history))
        row["cg_iterations"] = int(sum(h.get("cg_iterations", 0) for h in sol.history))
    return row, sol


def compare(disc, sol: ep.Solution, ref: ep.Solution) -> dict:
    stress = energy_norm_sq(disc, sol.sigma - ref.sigma, sol.xi - ref.xi) / energy_norm_sq(disc, ref.sigma, ref.xi)
    return {"dU_rel": abs(sol.U - ref.U) / abs(ref.U), "stress_err_energy": float(np.sqrt(stress)),
            "same_active": bool(np.array_equal(sol.active, ref.active)),
            "same_plastic": bool(np.array_equal(sol.plastic, ref.plastic))}


def measure(mode: str, out: Path) -> dict:
    quick = mode == "quick"
    methods = [m for m in ("conic", "uzawa", "uzawa-fast", "newton") if m in ep.METHODS]
    elastic_solve_time(case("cylinder_2d", [8, 4])[1])  # load MKL and start its threads before timing
    if quick:
        cases = [case("cylinder_2d", [40, 20]), case("cylinder_2d", [40, 20], 1e-3),
                 case("cylinder_2d", [40, 20], 1e-3, 6.0), case("sphere_block_3d", [10, 10, 6], 1e-3)]
        big = case("sphere_block_3d", [16, 16, 8])
    else:
        cases = [case("cylinder_2d", [80, 40]), case("cylinder_2d", [80, 40], 1e-3),
                 case("cylinder_2d", [80, 40], 1e-3, 6.0), case("sphere_quarter_3d", [8, 8, 8], 1e-3),
                 case("sphere_quarter_3d", [8, 8, 8], 1e-3, 3.0),
                 case("sphere_block_3d", [16, 16, 8], 1e-3), case("sphere_block_3d", [16, 16, 8], 1e-3, 3.0)]
        big = case("sphere_block_3d", [34, 34, 16])
    results = {"quick": quick, "machine": {"cpus": os.cpu_count(), "loadavg_start": os.getloadavg()},
               "tol": TOL, "cases": []}
    for label, disc in cases + [big]:
        is_big = label == big[0]
        entry = {"case": label, "n_elements": disc.n_elements, "n_free": disc.n_free, "H": disc.material.hardening,
                 "E": disc.material.E, "elastic_solve": elastic_solve_time(disc), "runs": []}
        sols = {}
        for m in methods:
            if is_big and m == "conic":
                entry["runs"].append({"method": m, "status": "skipped",
                                      "note": "interior point not run at this size (minutes per solve)"})
                continue
            opts = {"tol": TOL} if m != "conic" else {}
            if m in ("uzawa", "uzawa-fast"):
                opts["max_iter"] = 20000
            row, sol = run_method(disc, m, **opts)
            sols[m] = sol
            entry["runs"].append(row)
            print(f"{label:40s} {m:11s} {row['status']:10s} {row['time_s']:8.2f} s  it {row['iterations']:5d}  "
                  f"kkt {row['kkt_worst']:.1e}  U {row['U']:.8g}", flush=True)
        if "conic" in sols:
            ref_name, ref = "conic", sols["conic"]
        else:  # no interior point at this size: Newton to round-off instead
            ref_name, ref = f"newton with tol {REF_TOL:g}", ep.solve(disc, "newton", tol=REF_TOL)
            entry["reference_kkt_worst"] = ref.kkt.worst
        entry["reference"] = ref_name
        for row in entry["runs"]:
            if row["method"] in sols and row["method"] != "conic":
                row["vs_reference"] = compare(disc, sols[row["method"]], ref)
        done = [r for r in entry["runs"] if r.get("status") == "converged" and r["kkt_worst"] <= TOL]
        fastest = min(done, key=lambda r: r["time_s"]) if done else None
        entry["fastest"] = fastest["method"] if fastest else None
        entry["fastest_over_elastic"] = fastest["time_s"] / entry["elastic_solve"]["total_s"] if fastest else None
        uz = next((r for r in entry["runs"] if r["method"] == "uzawa" and "time_s" in r), None)
        entry["uzawa_over_fastest"] = uz["time_s"] / fastest["time_s"] if (uz and fastest) else None
        results["cases"].append(entry)
        print(f"  elastic solve {entry['elastic_solve']['total_s']:.2f} s; fastest {entry['fastest']} = "
              f"{entry['fastest_over_elastic']:.1f}x elastic" if fastest else "  none converged", flush=True)
    results["machine"]["loadavg_end"] = os.getloadavg()
    return results


TITLE = "Every method on the same problems (issue 4)"


def markdown(results: dict) -> str:
    """The report's body: one table per case (discussion and targets: README.md)."""
    lines = [f"Tolerance: every KKT residual <= {results['tol']:g}. Machine: {results['machine']['cpus']} cores, "
             f"load average at start {results['machine']['loadavg_start'][0]:.1f}, at end "
             f"{results['machine']['loadavg_end'][0]:.1f}.", ""]
    for e in results["cases"]:
        el = e["elastic_solve"]
        lines += [f"### {e['case']} ({e['n_elements']} elements, {e['n_free']} dofs)", "",
                  f"One elastic solve (PARDISO): {el['total_s']:.2f} s (assembly {el['assembly_s']:.2f}, "
                  f"analysis+factorisation {el['factorization_s']:.2f}, solve {el['solve_s']:.3f}). "
                  f"Fastest converged: **{e['fastest']}**"
                  + (f", {e['fastest_over_elastic']:.1f}x the elastic solve" if e["fastest_over_elastic"] else "")
                  + (f"; plain Uzawa / fastest = {e['uzawa_over_fastest']:.1f}" if e["uzawa_over_fastest"] else "")
                  + f". Reference for the errors: {e['reference']}"
                  + (f" (KKT {e['reference_kkt_worst']:.1e})" if "reference_kkt_worst" in e else "") + ".", "",
                  "| method | status | time (s) | iterations | KKT worst | U | dU rel | stress err | same active | same plastic |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in e["runs"]:
            if r.get("status") == "skipped":
                lines.append(f"| {r['method']} | skipped: {r['note']} | | | | | | | | |")
                continue
            v = r.get("vs_reference", {"dU_rel": float("nan"), "stress_err_energy": float("nan"),
                                           "same_active": "(reference)", "same_plastic": "(reference)"})
            lines.append(f"| {r['method']} | {r['status']} | {r['time_s']:.2f} | {r['iterations']} | {r['kkt_worst']:.1e} | "
                         f"{r['U']:.8g} | {v.get('dU_rel', float('nan')):.1e} | {v.get('stress_err_energy', float('nan')):.1e} | "
                         f"{v.get('same_active', '-')} | {v.get('same_plastic', '-')} |")
        notes = [f"{r['method']}: {r['message']}" for r in e["runs"] if r.get("message")]
        lines += ["", "Paths taken: " + "; ".join(notes) + "."] if notes else []
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    return run_record(__doc__, "small meshes only", HERE, TITLE, "methods benchmark", measure, markdown, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
