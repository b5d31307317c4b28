"""Performance profiles of every registered method on the suite of instances
(problems/suite/): each method on each instance in its own child process, with the
solver's time limit and a hard limit (the process is killed past it), every answer
certified at one tolerance; the fraction solved, the shifted geometric means of the
times (shift 1 s, a failure counted at the time limit) and the profiles of Dolan & Moré.

    python benchmarks/suite/run.py [--quick] [--out DIR] [--report]
           [--time-limit S] [--tol T] [--max-elements N] [--methods m1,m2,...]
"""

from __future__ import annotations

import math
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import ROOT, peak_memory, run_child, run_record  # noqa: E402

SUITE = ROOT / "problems" / "suite"
#: elements of each instance, measured by ep.discretize(ep.load_problem(path)) (problems/suite/README.md)
ELEMENTS = {
    "cyl2d-1k": 1_024, "punch2d-msh": 1_592, "quarter3d-3k": 3_072, "expr2d-4k": 3_600, "flat2d-4k": 4_096,
    "expr3d-5k": 5_184, "flat3d-5k": 5_184, "cyl2d-6k": 6_400, "cyl2d-6k-soft": 6_400, "sphere3d-12k": 12_288,
    "sphere3d-12k-soft": 12_288, "cyl2d-crossed-13k": 12_800, "sphere3d-98k": 98_304, "cyl2d-100k": 102_400,
    "box3d-415k": 414_720, "box3d-1m": 1_007_616,
    "sphere-axi-2k": 1_952, "bcone-axi-18k": 18_107, "sphere-axi-19k": 18_902,
}
QUICK = ["cyl2d-1k", "punch2d-msh", "quarter3d-3k", "expr2d-4k"]
TITLE = "Performance profiles on the suite of instances"


def child(spec: dict) -> dict:
    """One method on one instance: warm the method up (its first imports), then arm
    the hard limit (SIGALRM's default action ends the process, even inside native
    code) and solve; the record of elastoplast.studies.suite.run_instance with the
    process's peak memory."""
    from elastoplast.studies.campaign import warm_up
    from elastoplast.studies.suite import run_instance

    warm_up([spec["method"]])
    signal.alarm(max(1, math.ceil(spec["hard_limit"])))
    rec = run_instance(spec)
    signal.alarm(0)
    rec["peak_mb"] = peak_memory() / 2**20
    return rec


def run(mode: str, out: Path, time_limit: float | None = None, tol: float = 1e-6, max_elements: int | None = None,
        methods: str | None = None) -> dict:
    import elastoplast as ep

    quick = mode == "quick"
    time_limit = time_limit or (20.0 if quick else 30.0)
    hard = 2 * time_limit + 30.0  # reading, discretising, CVXPY's compilation and the certificate come on top
    max_elements = max_elements or 20_000
    files = {p.stem: p for p in sorted(SUITE.glob("*.toml"))}
    unknown = sorted(set(files) - set(ELEMENTS))
    for name in unknown:  # an instance added since: count it
        ELEMENTS[name] = ep.discretize(ep.load_problem(files[name])).n_elements
    names = QUICK if quick else sorted((n for n in files if ELEMENTS[n] <= max_elements), key=lambda n: ELEMENTS[n])
    left_out = {n: ELEMENTS[n] for n in files if n not in names}
    chosen = methods.split(",") if methods else list(ep.METHODS)
    runs = []
    for name in names:
        for method in chosen:
            spec = {"method": method, "name": name, "problem": str(files[name]), "hard_limit": hard,
                    "options": {"tol": tol, "time_limit": time_limit, "progress": False}}
            t0 = time.perf_counter()
            rec = run_child(__file__, spec)
            wall = time.perf_counter() - t0
            if "error" in rec and "status" not in rec:  # the child died: killed at the hard limit, or crashed
                killed = wall >= hard
                rec = {"method": method, "instance": name, "status": "killed" if killed else "error",
                       "message": (f"killed at the hard limit of {hard:g} s" if killed else rec["error"]),
                       "n_elements": ELEMENTS[name]}
            rec["process_wall_s"] = wall
            rec.pop("traceback", None)
            runs.append(rec)
            print(f"{name} ({ELEMENTS[name]:,}) {method}: {rec['status']}"
                  + (f" {rec['time_s']:.3g} s" if rec.get("time_s") is not None else "")
                  + f" [process {wall:.1f} s]", flush=True)
    from elastoplast.studies.suite import profile_record

    record = profile_record(runs, tol, time_limit, suite="problems/suite")
    return {**record, "mode": mode, "hard_limit_s": hard, "max_elements": max_elements, "runs": runs,
            "left_out": left_out, "machine_cores": __import__("os").cpu_count()}


def render(res: dict) -> str:
    from elastoplast.studies.suite import profile_markdown

    body = profile_markdown(res)
    if res.get("left_out"):
        body += ("\nLeft out of this run (more than " + f"{res['max_elements']:,} elements, or not in the quick set): "
                 + ", ".join(f"{n} ({e:,} elements)" for n, e in sorted(res["left_out"].items(), key=lambda x: x[1]))
                 + ".\n")
    peak = {m: max((r.get("peak_mb") or 0.0) for r in res["runs"] if r["method"] == m) for m in res["methods"]}
    body += ("\nPeak memory of a run, per method (MiB, the child process's VmHWM): "
             + ", ".join(f"{m} {v:.0f}" for m, v in peak.items()) + ".\n")
    body += (f"\nEach run in its own process: the solver's time limit {res['time_limit']:g} s, the process killed "
             f"at {res['hard_limit_s']:g} s; total {res.get('total_time_s', float('nan'))} s.\n")
    return body


def plots(res: dict, out: Path) -> None:
    from elastoplast.plots.figures import plot_profile

    plot_profile(res["profile"], out / "profile.png", taus=res["taus"],
                 title=f"{len(res['instances'])} instances, KKT ≤ {res['tol']:g}, time limit {res['time_limit']:g} s")


def main(argv=None) -> int:
    return run_record(__doc__, "four small instances (2D, 3D, a gmsh mesh, an expression obstacle)",
                      Path(__file__).parent, TITLE, "suite", run, render, plots=plots, argv=argv, child=child,
                      options={"--time-limit": {"type": float, "help": "solver time limit per run, s "
                                                                       "(default 30; quick 20)"},
                               "--tol": {"type": float, "default": 1e-6, "help": "certified tolerance (1e-6)"},
                               "--max-elements": {"type": int, "help": "largest instance run (default 20,000)"},
                               "--methods": {"help": "comma-separated methods (default: every registered one)"}})


if __name__ == "__main__":
    sys.exit(main())
