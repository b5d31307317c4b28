"""uzawa-fast's two candidates measured against each other and plain Uzawa (issue 4, item 2).

    python benchmarks/methods/accelerated.py           # 144 s wall in the recorded run, 2 cores
    python benchmarks/methods/accelerated.py --quick   # small meshes, a few cases, into quick/
    python benchmarks/methods/accelerated.py --report  # only accelerated.md again, from accelerated.json

Writes ``accelerated.json`` and ``accelerated.md`` beside this file (``--out``
to change). Two parts, all stopping on the certificate (docs/certificate.md):

1. the penalty r of ALG2 (both splittings, I and C) on small meshes, iterations
   to KKT <= 1e-8, certificate at every iteration;
2. plain Uzawa, FISTA with restart and ALG2 at two penalties on cylinder_2d
   80x40, sphere_quarter_3d 8x8x8 and sphere_block_3d 16x16x8, at H = E/10,
   E/100, E/1000 and forces F, 3F, 6F: iterations and wall time (set-up
   included) to KKT <= 1e-6 and <= 1e-8, read off one run to 1e-8 whose
   certificate is evaluated every 5 iterations (so counts are multiples of 5,
   times include the checks). The U of each run is compared with Newton's at
   KKT <= 1e-11.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import elastoplast as ep
from elastoplast.solvers.accelerated import FastOptions, solve_alg2, solve_uzawa_fast
from elastoplast.problem.definition import problem_from_dict, read_toml
from elastoplast.solvers.uzawa import UzawaOptions, solve_uzawa

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
PROBLEMS = HERE.parents[1] / "problems"
TOLS = (1e-6, 1e-8)
CHECK = 5
#: ALG2 penalties measured in part 2 (C splitting, r in units of the stiffness C)
PENALTIES = (0.25, 0.4)
TITLE = "uzawa-fast: FISTA with restart against ALG2 and plain Uzawa"


def case(name: str, divisions, hardening_over_E: float, force_factor: float):
    d = read_toml(PROBLEMS / f"{name}.toml")
    d["mesh"]["divisions"] = list(divisions)
    d["material"]["hardening"] = hardening_over_E * d["material"]["E"]
    d["load"]["force"] *= force_factor
    label = f"{name} {'x'.join(map(str, divisions))} H=E*{hardening_over_E:g} F*{force_factor:g}"
    return label, ep.discretize(problem_from_dict(d, PROBLEMS))


def methods(check: int):
    out = {
        "uzawa": lambda disc, tol: solve_uzawa(disc, UzawaOptions(tol=tol, max_iter=20000, check_every=check)),
        "fista": lambda disc, tol: solve_uzawa_fast(disc, FastOptions(tol=tol, max_iter=20000, check_every=check)),
    }
    for r in PENALTIES:
        out[f"alg2 C r={r:g}"] = (lambda r: lambda disc, tol: solve_alg2(
            disc, FastOptions(variant="alg2", splitting="stiffness", penalty=r, tol=tol, max_iter=20000,
                              check_every=check)))(r)
    return out


def reached(sol: ep.Solution, tol: float) -> dict:
    """Iteration and wall time of the first certificate evaluation with every residual <= tol."""
    for h in sol.history:
        if h["kkt_worst"] <= tol:
            return {"iterations": h["iteration"], "time_s": h["time_s"]}
    return {"iterations": None, "time_s": None}


def penalty_sweep(quick: bool) -> list[dict]:
    rows = []
    cases = [("cylinder_2d", [40, 20], 1e-3, 1.0), ("cylinder_2d", [40, 20], 1e-3, 6.0),
             ("sphere_quarter_3d", [6, 6, 6], 1e-3, 6.0)]
    grid = {"stiffness": (0.1, 0.15, 0.25, 0.4, 0.7, 1.0), "identity": (0.2, 0.3, 0.6, 1.0)}
    for name, div, h, ff in cases[:2] if quick else cases:
        label, disc = case(name, div, h, ff)
        row = {"case": label, "alg2": {}}
        for split, rs in grid.items():
            for r in rs:
                sol = solve_alg2(disc, FastOptions(variant="alg2", splitting=split, penalty=r, tol=1e-8,
                                                   max_iter=3000, check_every=1))
                row["alg2"][f"{split} r={r:g}"] = sol.iterations if sol.converged else None
        for m, fn in methods(1).items():
            if not m.startswith("alg2"):
                row[m] = fn(disc, 1e-8).iterations
        print(label, row, flush=True)
        rows.append(row)
    return rows


def comparison(quick: bool) -> list[dict]:
    meshes = ([("cylinder_2d", [40, 20]), ("sphere_quarter_3d", [6, 6, 6])] if quick else
              [("cylinder_2d", [80, 40]), ("sphere_quarter_3d", [8, 8, 8]), ("sphere_block_3d", [16, 16, 8])])
    hs = (1e-3,) if quick else (1e-1, 1e-2, 1e-3)
    rows = []
    for name, div in meshes:
        for h in hs:
            for ff in (1.0, 3.0, 6.0):
                label, disc = case(name, div, h, ff)
                ref = ep.solve(disc, "newton", tol=1e-11)
                entry = {"case": label, "n_elements": disc.n_elements, "n_plastic": int(ref.plastic.sum()),
                         "U_newton": ref.U, "runs": {}}
                for m, fn in methods(CHECK).items():
                    t0 = time.perf_counter()
                    sol = fn(disc, TOLS[-1])
                    wall = time.perf_counter() - t0
                    entry["runs"][m] = {"status": sol.status.value, "wall_s": wall, "setup_s": sol.timings["setup"],
                                        "dU_rel": abs(sol.U - ref.U) / abs(ref.U),
                                        **{f"{t:g}": reached(sol, t) for t in TOLS}}
                print(label, {m: (r["1e-08"]["iterations"], round(r["wall_s"], 2)) for m, r in entry["runs"].items()},
                      flush=True)
                rows.append(entry)
    return rows


def markdown(res: dict) -> str:
    lines = [f"Machine: {res['machine']['cpus']} cores, load average {res['machine']['loadavg_start'][0]:.1f} at "
             f"the start, {res['machine']['loadavg_end'][0]:.1f} at the end; run time {res['run_s']:.0f} s.", "",
             "## 1. ALG2's penalty r (iterations to KKT <= 1e-8, certificate every iteration)", ""]
    keys = list(res["sweep"][0]["alg2"]) if res["sweep"] else []
    lines += ["| case | uzawa | fista | " + " | ".join(f"ALG2 {k}" for k in keys) + " |",
              "|---" * (3 + len(keys)) + "|"]
    for row in res["sweep"]:
        lines.append(f"| {row['case']} | {row['uzawa']} | {row['fista']} | "
                     + " | ".join(str(row["alg2"][k]) for k in keys) + " |")
    names = list(res["comparison"][0]["runs"]) if res["comparison"] else []
    lines += ["", "## 2. Iterations / wall time (s, set-up included) to KKT <= 1e-6 and <= 1e-8", "",
              "Certificate every 5 iterations. `plastic`: plastic elements of the solution.", "",
              "| case | plastic | " + " | ".join(f"{m} 1e-6" + " | " + f"{m} 1e-8" for m in names) + " | fastest 1e-8 |",
              "|---" * (3 + 2 * len(names)) + "|"]
    for e in res["comparison"]:
        cells, best = [], (None, float("inf"))
        for m in names:
            r = e["runs"][m]
            for t in ("1e-06", "1e-08"):
                it, ts = r[t]["iterations"], r[t]["time_s"]
                cells.append("-" if it is None else f"{it} / {ts:.2f}")
            if r["1e-08"]["time_s"] is not None and r["1e-08"]["time_s"] < best[1]:
                best = (m, r["1e-08"]["time_s"])
        lines.append(f"| {e['case']} | {e['n_plastic']} | " + " | ".join(cells) + f" | {best[0]} |")
    lines += ["", "Largest |U - U_newton| / U_newton over all runs: "
              f"{max(r['dU_rel'] for e in res['comparison'] for r in e['runs'].values()):.1e}.", ""]
    return "\n".join(lines)


def measure(mode: str, out: Path) -> dict:
    quick = mode == "quick"
    t0 = time.perf_counter()
    res = {"quick": quick, "machine": {"cpus": os.cpu_count(), "loadavg_start": os.getloadavg()}}
    res["sweep"] = penalty_sweep(quick)
    res["comparison"] = comparison(quick)
    res["machine"]["loadavg_end"] = os.getloadavg()
    res["run_s"] = time.perf_counter() - t0
    return res


def main(argv=None) -> int:
    return run_record(__doc__, "a few small cases", HERE, TITLE, "accelerated study", measure, markdown, argv=argv,
                      study="accelerated")


if __name__ == "__main__":
    sys.exit(main())
