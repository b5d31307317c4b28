"""The cost of a step of a loading path (Prandtl-Reuss, docs/evolution.md): each method
on 2D and 3D indentation paths of 20 steps (load, unload to a small force, reload
beyond), warm-started against cold (``solve_path(..., warm_start=False)``), and newton's
time per step against one Hencky newton solve of the same mesh at the path's largest force.

    python benchmarks/paths/run.py [--quick] [--out DIR] [--report] [--budget S]

Each (mesh, method, start) runs in its own child process (run_child), its peak memory its
own; the child times every step by the wall clock (from the end of one step to the end of
the next: building the step, the solve, the certificate, the step's records) and by the
process's CPU time, and reports each step's status and iterations. Runs go from the
smallest mesh to the largest; once ``--budget`` seconds have passed the rest are recorded
as skipped.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

TITLE = "Loading paths: the cost of a step, warm and cold"
#: the path as shares of the mesh's force F: 8 loading steps to F, 6 unloading to 0.05 F,
#: 6 reloading to 1.25 F (not returning exactly to F: no degenerate step)
SHARES = [i / 8 for i in range(1, 9)] + [0.85, 0.7, 0.5, 0.3, 0.15, 0.05] + [0.3, 0.6, 0.9, 1.05, 1.15, 1.25]
ITERATIVE = ("newton", "uzawa", "uzawa-fast")


def problem(dim: int, n: int) -> dict:
    """The 2D cylinder (problems/cylinder_2d.toml, [2n, n] divisions, F = 5000 N/mm) or
    the 3D sphere on a block (the built-in default, [2n, 2n, n], F = 11 kN), H = E/20."""
    if dim == 2:
        return {"mesh": {"generator": "rectangle", "size": [40.0, 20.0], "divisions": [2 * n, n], "grading": 2.0,
                         "contact_radius": 4.0},
                "material": {"E": 2e5, "nu": 0.3, "yield_stress": 1200.0, "hardening": 1e4},
                "obstacle": {"shape": "cylinder", "radius": 40.0}, "load": {"force": 5000.0}}
    return {"mesh": {"generator": "box", "size": [12.0, 12.0, 6.0], "divisions": [2 * n, 2 * n, n], "grading": 1.6,
                     "contact_radius": 2.5},
            "material": {"E": 2e5, "nu": 0.3, "yield_stress": 1500.0, "hardening": 1e4},
            "obstacle": {"shape": "sphere", "radius": 40.0}, "load": {"force": 11000.0}}


def child(spec: dict) -> dict:
    """One path by one method from one start, or (``method == "hencky"``) one Hencky
    newton solve at the path's largest force; armed with a hard limit (SIGALRM)."""
    import warnings

    import elastoplast as ep
    from elastoplast.studies.campaign import warm_up

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    disc = ep.discretize(ep.problem_from_dict(problem(spec["dim"], spec["n"])))
    t_disc = time.perf_counter() - t0
    forces = [s * disc.force for s in SHARES]
    method = "newton" if spec["method"] == "hencky" else spec["method"]
    warm_up([method])
    signal.alarm(int(spec["hard_limit"]))
    out = {"n_elements": disc.n_elements, "discretize_s": t_disc}
    if spec["method"] == "hencky":
        t0, c0 = time.perf_counter(), time.process_time()
        sol = ep.solve(disc.with_force(max(forces)), "newton", progress=False)
        out.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0, status=sol.status.value,
                   iterations=sol.iterations, kkt_worst=sol.kkt.worst)
    else:
        marks = [(time.perf_counter(), time.process_time())]

        def mark(step):
            marks.append((time.perf_counter(), time.process_time()))

        res = ep.solve_path(disc, forces, method, warm_start=spec["warm"], progress=False, callback=mark)
        wall = [b[0] - a[0] for a, b in zip(marks, marks[1:])]
        cpu = [b[1] - a[1] for a, b in zip(marks, marks[1:])]
        out.update(n_steps=len(forces), n_run=len(res.steps), converged=res.converged, total_s=res.time_s,
                   step_wall_s=wall, step_cpu_s=cpu, step_solver_s=[s.solution.time_s for s in res.steps],
                   iterations=[s.solution.iterations for s in res.steps],
                   statuses=[s.status.value for s in res.steps],
                   kkt_worst=max(s.solution.kkt.worst for s in res.steps),
                   warm_started=sum(s.warm_started for s in res.steps),
                   reverse_yield=sum(s.reverse_yield for s in res.steps), U=[s.U for s in res.steps])
    signal.alarm(0)
    out["peak_mb"] = peak_memory() / 2**20
    return out


def plan(mode: str) -> list[dict]:
    """The runs in order: every method, warm and cold, on the small meshes; the
    iterative methods on a 3D mesh of 12k; newton alone (the method for large meshes,
    and the issue's ratio to one Hencky solve) on the 100k meshes, warm first, the cold
    runs of those last (the budget may leave them out). Each mesh opens with its Hencky
    newton solve."""
    every, iterative = ["conic", "newton", "uzawa", "uzawa-fast"], ["newton", "uzawa", "uzawa-fast"]
    if mode == "quick":
        stages = [(2, 20, every, (True, False)), (3, 4, every, (True, False))]
    else:
        stages = [(2, 40, every, (True, False)), (3, 6, every, (True, False)), (3, 8, iterative, (True, False)),
                  (2, 160, ["newton"], (True,)), (3, 16, ["newton"], (True,)),
                  (2, 160, ["newton"], (False,)), (3, 16, ["newton"], (False,))]
    runs, meshes = [], set()
    for dim, n, methods, starts in stages:
        if (dim, n) not in meshes:
            meshes.add((dim, n))
            runs.append({"dim": dim, "n": n, "method": "hencky", "warm": None})
        for m in methods:
            chosen = starts if m in ITERATIVE else (False,)  # interior points always start cold
            runs += [{"dim": dim, "n": n, "method": m, "warm": w} for w in chosen]
    return runs


def run(mode: str, out: Path, budget: float | None = None) -> dict:
    budget = budget or (300.0 if mode == "quick" else 1100.0)
    t_start = time.perf_counter()
    records = []
    load = os.getloadavg()
    for spec in plan(mode):
        left = budget - (time.perf_counter() - t_start)
        label = f"{spec['dim']}D n={spec['n']} {spec['method']}" + (
            "" if spec["warm"] is None else (" warm" if spec["warm"] else " cold"))
        if left <= 30.0:
            records.append({**spec, "skipped": f"budget of {budget:g} s spent"})
            print(f"{label}: skipped (budget)", flush=True)
            continue
        t0 = time.perf_counter()
        hard = max(30, int(left))
        rec = run_child(__file__, {**spec, "hard_limit": hard})
        rec = {**spec, **rec, "process_wall_s": time.perf_counter() - t0}
        if "error" in rec and rec["process_wall_s"] >= hard:  # SIGALRM: what was left of the budget ran out
            rec["error"] = f"killed when the budget of {budget:g} s ran out ({hard} s left when it started)"
        records.append(rec)
        print(f"{label}: " + (rec["error"] if "error" in rec else
                              f"{rec['n_elements']:,} elements, " + (
                                  f"{rec['wall_s']:.2f} s" if spec["method"] == "hencky" else
                                  f"{rec['n_run']}/{rec['n_steps']} steps, {sum(rec['step_wall_s']):.1f} s")),
              flush=True)
    return {"mode": mode, "budget_s": budget, "shares": SHARES, "load_average_at_start": load,
            "machine_cores": os.cpu_count(), "runs": records}


def _mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


def summary_rows(res: dict) -> list[dict]:
    """One row per (mesh, method, start): mean, median and largest step wall time, CPU
    time per step, iterations per step, and newton's ratio to the Hencky solve."""
    hencky = {(r["dim"], r["n"]): r for r in res["runs"] if r["method"] == "hencky" and "wall_s" in r}
    rows = []
    for r in res["runs"]:
        if r["method"] == "hencky":
            continue
        row = {"dim": r["dim"], "n": r["n"], "method": r["method"], "start": "warm" if r["warm"] else "cold"}
        if "step_wall_s" not in r:
            rows.append({**row, "note": r.get("skipped") or r.get("error", "")})
            continue
        wall = sorted(r["step_wall_s"])
        h = hencky.get((r["dim"], r["n"]))
        rows.append({**row, "n_elements": r["n_elements"], "steps": f"{r['n_run']}/{r['n_steps']}",
                     "converged": r["converged"], "mean_s": _mean(r["step_wall_s"]), "median_s": wall[len(wall) // 2],
                     "max_s": wall[-1], "cpu_mean_s": _mean(r["step_cpu_s"]), "iter_mean": _mean(r["iterations"]),
                     "kkt_worst": r["kkt_worst"], "peak_mb": r["peak_mb"],
                     "hencky_s": h["wall_s"] if h else None,
                     "ratio_to_hencky": _mean(r["step_wall_s"]) / h["wall_s"] if h else None})
    return rows


def render(res: dict) -> str:
    rows = summary_rows(res)
    la = res.get("load_average_at_start", [float("nan")] * 3)
    lines = [f"Path of {len(res['shares'])} steps per mesh (shares of F: {', '.join(f'{s:g}' for s in res['shares'])}); "
             f"each method at its default tolerance; every run in its own process. Load average when the run "
             f"started: {la[0]:.2f} on {res['machine_cores']} cores (the machine is shared: wall times carry that "
             "noise; the CPU time per step is given beside them).", "",
             "| dim | elements | method | start | steps | mean step [s] | median [s] | max [s] | CPU/step [s] | "
             "iterations/step | worst KKT | peak [MiB] | Hencky newton [s] | step / Hencky |",
             "|" + "---|" * 14]
    for r in rows:
        if "note" in r:
            lines.append(f"| {r['dim']} | – | {r['method']} | {r['start']} | – | {r['note']} |" + " |" * 9)
            continue
        ratio = "–" if r["ratio_to_hencky"] is None or r["method"] != "newton" else f"{r['ratio_to_hencky']:.2f}"
        hencky = "–" if r["hencky_s"] is None else f"{r['hencky_s']:.2f}"
        lines.append(f"| {r['dim']} | {r['n_elements']:,} | {r['method']} | {r['start']} | {r['steps']} | "
                     f"{r['mean_s']:.3g} | {r['median_s']:.3g} | {r['max_s']:.3g} | {r['cpu_mean_s']:.3g} | "
                     f"{r['iter_mean']:.1f} | {r['kkt_worst']:.1e} | {r['peak_mb']:.0f} | {hencky} | {ratio} |")
    pairs = {}
    for r in rows:
        if "mean_s" in r:
            pairs.setdefault((r["dim"], r["n_elements"], r["method"]), {})[r["start"]] = r["mean_s"]
    speed = [f"{m} {d}D {n:,}: {p['cold'] / p['warm']:.2f}" for (d, n, m), p in pairs.items() if {"warm", "cold"} <= set(p)]
    if speed:
        lines += ["", "Cold over warm mean step time (above 1: the warm start pays): " + "; ".join(speed) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return run_record(__doc__, "a 2D and a 3D mesh of about 1,500 elements, every method", Path(__file__).parent,
                      TITLE, "paths", run, render, argv=argv, child=child,
                      options={"--budget": {"type": float, "help": "seconds after which the remaining runs are "
                                                                   "skipped (default 1100; quick 300)"}})


if __name__ == "__main__":
    sys.exit(main())
