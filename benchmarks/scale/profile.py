"""Where Newton's time goes at a million tetrahedra (issue "Newton at the speed of its linear algebra").

    python benchmarks/scale/profile.py            # n = 17 and 35: 118k and 1.03M tetrahedra (about 8 minutes here)
    python benchmarks/scale/profile.py --quick    # n = 8 and 13: 12k and 53k tetrahedra (about a minute), into quick/
    python benchmarks/scale/profile.py --report   # profile.md again from profile.json

The default 3D problem (``elastoplast/data/default.toml``) with ``[mesh] divisions =
[2n, 2n, n]`` (24 n^3 tetrahedra), solved by ``ep.solve(disc, "newton", tol=1e-8)``:
at these sizes ``linear_solver="auto"`` takes the AMG path
(``NEWTON_AMG_FROM_ELEMENTS``: 20,000 elements in 3D; checked in the record). Each
size runs in its own process under pyinstrument (a statistical profiler: it samples
the Python stack, and time spent in compiled code -- numpy, SciPy's sparse kernels,
pyamg's C++ -- counts to the Python frame that called it, so the wall time of the
native kernels is seen at the level of the call that made them; the record checks
that the sampled time covers the measured wall time). Mesh generation
(``problem_from_dict``) and discretisation (``ep.discretize``) are timed apart.

Recorded per size: wall times of mesh generation, discretisation and solve (and the
solve's CPU time), the peak memory of the process (``peak_memory()``, which includes
the profiler's samples), Newton steps, per step the CG iterations, whether a new AMG
hierarchy was set up, the forcing term, the line-search step and the KKT residual
(from ``Solution.history``), Newton's own timers (``Solution.timings``), and the
profile's sampled time grouped into categories (assembly, AMG set-up, CG, line search,
certificate, ...; :data:`CATEGORIES`) with the heaviest frames. The profiler's full
text output is written beside the record as ``profile_n<n>.txt``. The full mode runs
each size a second time in a process without the profiler (``control``): the
profiler's overhead in time and memory. pyinstrument charges the time since its last
sample to the stack at the first Python call or return after ``interval``, so work
shorter than the interval between two calls (CG's vector updates between a
matrix-vector product and a V-cycle) can be charged to the next call: small
categories are exact only to about one interval per sample.

Writes ``profile.json`` and ``profile.md`` (a side study of benchmarks/scale) and the
``profile_n<n>.txt`` files beside this file (``--out`` to change).
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record, write_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TOL = 1e-8
TITLE = "Where Newton's time goes (profile of the AMG Newton solve)"
STUDY = "profile"
SIZES = [17, 35]          # 117,912 and 1,029,000 tetrahedra
QUICK_SIZES = [10, 13]    # 24,000 and 52,728 (n = 8, 12,288, is below NEWTON_AMG_FROM_ELEMENTS: PARDISO)
#: pyinstrument's sampling interval (s): 1 ms on the quick sizes; 10 ms on the large
#: ones, where 1 ms would keep ~250k stack samples (hundreds of MB) in the process
INTERVAL = {"quick": 0.001, "full": 0.01}

#: the categories of the solve, (group, item), in the order of the report
CATEGORIES = [
    ("set-up", "scaling, block layout, elastic stiffness, near-null space"),
    ("set-up", "choice of the linear solver (the PARDISO probe)"),
    ("assembly", "plastic tangents C_ep - C into the BSR matrix"),
    ("assembly", "BSR matrix, K e_c"),
    ("AMG set-up", "smoothed-aggregation hierarchy (pyamg)"),
    ("face systems", "Dirichlet rows, bordered preconditioner (z = M b)"),
    ("CG iterations", "preconditioner (V-cycle, U elimination)"),
    ("CG iterations", "matrix-vector products"),
    ("CG iterations", "vector operations"),
    ("CG iterations", "embedding, residual check"),
    ("Newton step", "active set, right-hand side, diagonal"),
    ("line search", "return mapping"),
    ("line search", "strains B u"),
    ("line search", "internal force B^T sigma"),
    ("line search", "energy"),
    ("line search", "consistent tangent (accepted point)"),
    ("line search", "projection, Armijo test"),
    ("start point", "evaluation at u = 0"),
    ("certificate", "each iterate (Monitor.check)"),
    ("certificate", "the answer in the user's units"),
    ("imports", "modules imported on first use (pyamg)"),
    ("other", "rest of the solve"),
]
CAT = {item: (g, item) for g, item in CATEGORIES}


def discretization_timed(n: int):
    """The default 3D problem with divisions [2n, 2n, n]: ``(disc, mesh_s, discretize_s)``."""
    import elastoplast as ep
    from elastoplast.problem.definition import problem_from_dict, read_toml

    d = read_toml(ROOT / "elastoplast" / "data" / "default.toml")
    d["mesh"]["divisions"] = [2 * n, 2 * n, n]
    t0 = time.perf_counter()
    problem = problem_from_dict(d)
    t1 = time.perf_counter()
    disc = ep.discretize(problem)
    return disc, t1 - t0, time.perf_counter() - t1


# ----------------------------------------------------------------------------
# the profile's tree into categories
# ----------------------------------------------------------------------------


def frame_key(frame) -> str:
    """``Class.function`` (or ``function``) @ the file's name."""
    cls = frame.class_name
    name = f"{cls}.{frame.function}" if cls and not cls.startswith("pybind11") else frame.function
    return f"{name}@{Path(frame.file_path or '?').name}"


def classify(path: list[str]) -> tuple[str, str]:
    """The category of time spent at the innermost frame of ``path`` (frame keys from
    the solve's frame inwards)."""
    has = set(path).__contains__

    def any_of(*keys: str) -> bool:
        return any(has(k) for k in keys)

    if has("choose_backend@newton.py"):
        return CAT["choice of the linear solver (the PARDISO probe)"]
    if has("_find_and_load@<frozen importlib._bootstrap>"):
        return CAT['modules imported on first use (pyamg)']
    if any_of("Monitor.solution@loop.py", "confirm@loop.py"):
        return CAT["the answer in the user's units"]
    if has("Monitor.check@loop.py"):
        return CAT['each iterate (Monitor.check)']
    if has("line_search@newton.py"):
        if has("State.with_tangent@hessian.py"):
            return CAT['consistent tangent (accepted point)']
        if has("return_mapping@material.py"):
            return CAT['return mapping']
        if has("Discretization.strain@discretize.py"):
            return CAT['strains B u']
        if has("Discretization.internal_force@discretize.py"):
            return CAT['internal force B^T sigma']
        if any_of("energy@newton.py", "energy_density@kkt.py"):
            return CAT['energy']
        return CAT['projection, Armijo test']
    if has("_newton_loop@newton.py") and has("evaluate@newton.py"):
        return CAT['evaluation at u = 0']
    if has("AMGHessian.update@hessian.py"):
        return CAT['plastic tangents C_ep - C into the BSR matrix'] if has("assemble@assembly.py") else CAT['BSR matrix, K e_c']
    if has("AMG.__init__@amg.py"):
        return CAT['smoothed-aggregation hierarchy (pyamg)']
    if has("FaceSystems._system@amg.py"):
        return CAT['Dirichlet rows, bordered preconditioner (z = M b)']
    if has("pcg@amg.py"):
        if has("BorderedSystem.precondition@amg.py"):
            return CAT['preconditioner (V-cycle, U elimination)']
        if has("BorderedSystem.matvec@amg.py"):
            return CAT['matrix-vector products']
        return CAT['vector operations']
    if has("FaceSystems._solve@amg.py"):
        return CAT['embedding, residual check']
    if has("newton_direction@newton.py"):
        return CAT['active set, right-hand side, diagonal']
    if not has("_newton_loop@newton.py"):
        return CAT['scaling, block layout, elastic stiffness, near-null space']
    return CAT['rest of the solve']


def find_frame(frame, key: str):
    """The first frame (depth first) whose key is ``key``."""
    stack = [frame]
    while stack:
        f = stack.pop()
        if not f.is_synthetic and frame_key(f) == key:
            return f
        stack.extend(reversed(f.children))
    return None


def breakdown(solve_frame) -> tuple[dict[str, float], dict[str, list[dict]]]:
    """Sampled seconds of the solve per category (every sample goes to exactly one),
    and the heaviest functions inside it: the package's own by inclusive seconds
    (outermost call on each stack, so recursion is not counted twice), and any by
    self seconds (where the time is spent, native kernels included)."""
    cats: dict[str, float] = defaultdict(float)
    inclusive: dict[str, float] = defaultdict(float)
    self_time: dict[str, float] = defaultdict(float)
    where: dict[str, str] = {}

    def walk(f, path: list[str]) -> None:
        key = frame_key(f)
        path = path + [key]
        if path.count(key) == 1:
            inclusive[key] += f.time
        s = f.total_self_time
        self_time[key] += s
        where.setdefault(key, f"{f.file_path_short}:{f.line_no}")
        g, item = classify(path)
        cats[f"{g} | {item}"] += s
        for c in f.children:
            if not c.is_synthetic:
                walk(c, path)

    walk(solve_frame, [])
    def rows(keys):
        return [{"frame": k, "where": where[k], "inclusive_s": inclusive[k], "self_s": self_time[k]} for k in keys]

    own = [k for k in inclusive if "elastoplast/" in where[k]]
    return dict(cats), {"inclusive": rows(sorted(own, key=inclusive.get, reverse=True)[:30]),
                        "self": rows(sorted(self_time, key=self_time.get, reverse=True)[:30])}


# ----------------------------------------------------------------------------
# one size in its own process
# ----------------------------------------------------------------------------


def run_control(n: int) -> dict:
    """The same solve without the profiler (its overhead in time and memory)."""
    import elastoplast as ep

    disc, mesh_s, disc_s = discretization_timed(n)
    w0, c0 = time.perf_counter(), time.process_time()
    sol = ep.solve(disc, "newton", tol=TOL)
    solve_s, solve_cpu = time.perf_counter() - w0, time.process_time() - c0
    return {"mesh_s": mesh_s, "discretize_s": disc_s, "solve_wall_s": solve_s, "solve_cpu_s": solve_cpu,
            "peak_gb": peak_memory() / 1e9, "newton_steps": sol.iterations, "status": sol.status.value,
            "cg_iterations": [row.get("cg_iterations") for row in sol.history[1:]],
            "timings": {k: float(v) for k, v in sol.timings.items()}}


def run_case(n: int, out: str, interval: float) -> dict:
    import numpy as np
    from pyinstrument import Profiler

    import elastoplast as ep
    from elastoplast.linalg.direct import pardiso_available
    from elastoplast.solvers.newton import NEWTON_AMG_FROM_ELEMENTS, choose_backend

    prof = Profiler(interval=interval, async_mode="disabled")
    prof.start()
    disc, mesh_s, disc_s = discretization_timed(n)
    w0, c0 = time.perf_counter(), time.process_time()
    sol = ep.solve(disc, "newton", tol=TOL)
    solve_s, solve_cpu = time.perf_counter() - w0, time.process_time() - c0
    prof.stop()
    peak = peak_memory()

    session = prof.last_session
    text = prof.output_text(unicode=False, color=False)
    Path(out, f"profile_n{n}.txt").write_text(text)
    root = session.root_frame()
    solve_frame = find_frame(root, "_solve_newton@newton.py")
    cats, top = breakdown(solve_frame)
    mesh_frame = find_frame(root, "problem_from_dict@definition.py")
    disc_frame = find_frame(root, "discretize@discretize.py")

    direct = "pardiso" if pardiso_available() else "splu"
    steps = []
    for row in sol.history[1:]:
        alpha = row.get("step")
        steps.append({"iteration": row["iteration"], "cg_iterations": row.get("cg_iterations"),
                      "amg_setup": bool(row.get("amg_setup")), "forcing": row.get("forcing"),
                      "cg_residual": row.get("cg_residual"), "alpha": alpha,
                      "trials": None if alpha is None else int(round(-math.log2(alpha))) + 1,
                      "kkt_worst": row["kkt_worst"], "n_plastic": row["n_plastic"], "n_active": row["n_active"],
                      "time_s": row["time_s"]})
    return {
        "n": n, "n_elements": disc.n_elements, "n_free": disc.n_free, "n_contact": disc.n_contact,
        "amg_from_elements": NEWTON_AMG_FROM_ELEMENTS[direct][3], "message": sol.message,
        "linear_solver": choose_backend(disc, "auto"),
        "status": sol.status.value, "kkt_worst": sol.kkt.worst, "U": sol.U, "newton_steps": sol.iterations,
        "amg_setups": sum(s["amg_setup"] for s in steps),
        "cg_iterations_total": int(np.sum([s["cg_iterations"] or 0 for s in steps])),
        "mesh_s": mesh_s, "discretize_s": disc_s, "solve_wall_s": solve_s, "solve_cpu_s": solve_cpu,
        "peak_gb": peak / 1e9, "interval_s": interval,
        "profile": {"sampled_solve_s": solve_frame.time, "sampled_mesh_s": mesh_frame.time if mesh_frame else None,
                    "sampled_discretize_s": disc_frame.time if disc_frame else None,
                    "sampled_total_s": root.time, "samples": session.sample_count, "categories": cats, "top_frames": top,
                    "text_file": f"profile_n{n}.txt"},
        "timings": {k: float(v) for k, v in sol.timings.items()},
        "steps": steps,
    }


def measure(mode: str, out: Path) -> dict:
    sizes = QUICK_SIZES if mode == "quick" else SIZES
    results = {"tol": TOL, "profiler": "pyinstrument " + _version("pyinstrument"), "records": []}
    for n in sizes:
        t0 = time.perf_counter()
        rec = run_child(__file__, {"n": n, "out": str(out.resolve()), "interval": INTERVAL[mode]})
        if "error" in rec:
            rec = {"n": n, **rec}
        rec["process_s"] = time.perf_counter() - t0
        if mode == "full" and "error" not in rec:
            rec["control"] = run_child(__file__, {"n": n, "control": True})
        results["records"].append(rec)
        print(f"n={n}: " + (f"error {rec['error']}" if "error" in rec else
              f"{rec['n_elements']:,} el, solve {rec['solve_wall_s']:.1f} s wall / {rec['solve_cpu_s']:.1f} s CPU, "
              f"{rec['newton_steps']} steps, CG {[s['cg_iterations'] for s in rec['steps']]}, "
              f"{rec['peak_gb']:.2f} GB; unprofiled {rec.get('control', {}).get('solve_wall_s', float('nan')):.1f} s "
              f"wall, {rec.get('control', {}).get('peak_gb', float('nan')):.2f} GB"), flush=True)
        write_record(out, results, TITLE, report, study=STUDY)
    return results


def _version(dist: str) -> str:
    from importlib.metadata import version

    return version(dist)


# ----------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------


def breakdown_table(recs: list[dict]) -> list[str]:
    head = "| group | item | " + " | ".join(f"{r['n_elements']:,}: s | share" for r in recs) + " |"
    lines = [head, "|---|---|" + "---|---|" * len(recs)]
    groups: list[str] = []
    for g, _ in CATEGORIES:
        if g not in groups:
            groups.append(g)
    for g in groups:
        cells = []
        for r in recs:
            c, tot = r["profile"]["categories"], r["profile"]["sampled_solve_s"]
            s = sum(v for k, v in c.items() if k.split(" | ")[0] == g)
            cells.append(f"**{s:.1f}** | **{100 * s / tot:.1f}%**")
        lines.append(f"| **{g}** | | " + " | ".join(cells) + " |")
        items = [i for gg, i in CATEGORIES if gg == g]
        if len(items) > 1:
            for item in items:
                cells = []
                for r in recs:
                    c, tot = r["profile"]["categories"], r["profile"]["sampled_solve_s"]
                    s = c.get(f"{g} | {item}", 0.0)
                    cells.append(f"{s:.1f} | {100 * s / tot:.1f}%")
                lines.append(f"| | {item} | " + " | ".join(cells) + " |")
    cells = [f"{r['profile']['sampled_solve_s']:.1f} | 100%" for r in recs]
    lines.append("| **solve (sampled)** | | " + " | ".join(cells) + " |")
    return lines


def report(results: dict) -> str:
    recs = [r for r in results["records"] if "error" not in r]
    lines = [f"The default 3D problem, divisions [2n, 2n, n], `ep.solve(disc, \"newton\", tol={results['tol']:g})` "
             f"(the AMG path, chosen by `linear_solver=\"auto\"`), each size in its own process under "
             f"{results['profiler']}. Wall seconds; the machine is shared, so the shares are the figures to read.",
             ""]
    for r in results["records"]:
        if "error" in r:
            lines.append(f"n = {r['n']}: error {r['error']}")
    lines += ["| n | tetrahedra | free dofs | linear solver | mesh s | discretise s | solve wall s | solve CPU s | "
              "sampled s | peak GB | Newton steps | AMG set-ups | CG iterations | status |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        lines.append(f"| {r['n']} | {r['n_elements']:,} | {r['n_free']:,} | {r['linear_solver']} | {r['mesh_s']:.1f} | {r['discretize_s']:.1f} | "
                     f"{r['solve_wall_s']:.1f} | {r['solve_cpu_s']:.1f} | {r['profile']['sampled_solve_s']:.1f} | "
                     f"{r['peak_gb']:.2f} | {r['newton_steps']} | {r['amg_setups']} | {r['cg_iterations_total']} | "
                     f"{r['status']}, KKT {r['kkt_worst']:.1e} |")
    lines += ["", "## Breakdown of the solve (sampled wall seconds, share of the solve)", "",
              "Every sample of the solve goes to one category, by the innermost frame of its stack "
              "that names one (`classify` in profile.py); the inclusive time of a category is that of "
              "everything it calls.", ""]
    lines += breakdown_table(recs)
    lines += ["", "## Newton's own timers (`Solution.timings`, wall s)", "",
              "| timer | " + " | ".join(f"{r['n_elements']:,}" for r in recs) + " |",
              "|---|" + "---|" * len(recs)]
    keys = list(dict.fromkeys(k for r in recs for k in r["timings"]))
    for k in keys:
        label = {"factorization": "factorization (AMG set-up + face systems)", "solve": "solve (CG)"}.get(k, k)
        lines.append(f"| {label} | " + " | ".join(f"{r['timings'].get(k, 0.0):.1f}" for r in recs) + " |")
    ctl = [r for r in recs if "control" in r and "error" not in r["control"]]
    if ctl:
        lines += ["", "## The profiler's overhead: the same solve in a process without it", "",
                  "| tetrahedra | solve wall s (profiled / not) | solve CPU s (profiled / not) | peak GB (profiled / not) "
                  "| samples | Newton steps | CG iterations per step (not profiled) |", "|---|---|---|---|---|---|---|"]
        for r in ctl:
            c = r["control"]
            lines.append(f"| {r['n_elements']:,} | {r['solve_wall_s']:.1f} / {c['solve_wall_s']:.1f} | "
                         f"{r['solve_cpu_s']:.1f} / {c['solve_cpu_s']:.1f} | {r['peak_gb']:.2f} / {c['peak_gb']:.2f} | "
                         f"{r['profile'].get('samples', '')} | {r['newton_steps']} / {c['newton_steps']} | "
                         f"{c['cg_iterations']} |")
    for r in recs:
        lines += ["", f"## Newton steps at {r['n_elements']:,} tetrahedra (n = {r['n']})", "",
                  "| step | CG iterations | new AMG hierarchy | forcing eta | CG residual | line-search alpha (trials) | "
                  "KKT after | plastic | active | time s |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for s in r["steps"]:
            f = "" if s["forcing"] is None else f"{s['forcing']:.1e}"
            cr = "" if s["cg_residual"] is None else f"{s['cg_residual']:.1e}"
            lines.append(f"| {s['iteration']} | {s['cg_iterations']} | {'yes' if s['amg_setup'] else ''} | {f} | {cr} | "
                         f"{s['alpha']:g} ({s['trials']}) | {s['kkt_worst']:.1e} | {s['n_plastic']} | {s['n_active']} | "
                         f"{s['time_s']:.1f} |")
    for r in recs:
        tot = r["profile"]["sampled_solve_s"]
        for kind, what, count in (("inclusive", "the package's frames by inclusive time", 20),
                                  ("self", "every frame by self time (the kernels themselves)", 15)):
            lines += ["", f"## Heaviest frames at {r['n_elements']:,} tetrahedra: {what} (within the solve; "
                      f"full profile in `{r['profile']['text_file']}`)", "",
                      "| frame | where | inclusive s | share | self s | share |", "|---|---|---|---|---|---|"]
            for t in r["profile"]["top_frames"][kind][:count]:
                lines.append(f"| `{t['frame'][:90]}` | {t['where']} | {t['inclusive_s']:.1f} | "
                             f"{100 * t['inclusive_s'] / tot:.1f}% | {t['self_s']:.1f} | {100 * t['self_s'] / tot:.1f}% |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return run_record(__doc__, "n = 8 and 13 (12k and 53k tetrahedra)", HERE, TITLE, "profile", measure, report,
                      argv=argv, study=STUDY,
                      child=lambda spec: run_control(spec["n"]) if spec.get("control") else
                      run_case(spec["n"], spec["out"], spec["interval"]))


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
