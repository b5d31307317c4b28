"""A million tetrahedra on one 2-core machine (issue 12): every method from 12k to 1M elements in one run.

    python benchmarks/scale/run.py            # full run: 12k .. 1.03M tetrahedra (about an hour here)
    python benchmarks/scale/run.py --quick    # 5k and 12k tetrahedra (about a minute), into quick/
    python benchmarks/scale/run.py --report   # REPORT.md and the plot again from results.json

The problem is the built-in default (a sphere pressed into a clamped block) with
``[mesh] divisions = [2n, 2n, n]`` (24 n^3 tetrahedra). Each case runs in its
own process, so its peak memory (VmHWM, which includes the mesh and the
discretisation) is its own: newton, uzawa and uzawa-fast to KKT <= 1e-8 on the
iterative path (AMG-CG) and on the direct one where it fits, one linear elastic
solve by AMG-CG (relative residual 1e-10) and by PARDISO where it fits, and the
conic reference on the small meshes (its growth sets ``CONIC_MAX_ELEMENTS``).
Every answer is compared with the direct Newton answer of the same mesh (U
relative, stresses in the energy norm); where no direct path runs, with the
AMG Newton answer. Times are wall and CPU seconds of the solve (after the
discretisation, which is timed apart); the machine is shared, so the ratios
inside this run, and the CPU times, are the figures to read.

Writes ``results.json``, ``REPORT.md`` and plots beside this file (``--out`` to change),
after every case (an interrupted run keeps what it measured).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record, write_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TOL = 1e-8
TITLE = "A million tetrahedra (issue 12)"
#: full run: n of divisions [2n, 2n, n] -> 24 n^3 tetrahedra (12k, 24k, 53k, 118k, 375k, 1.03M)
SIZES = [8, 10, 13, 17, 25, 35]
QUICK_SIZES = [6, 8]
#: which cases run up to (and including) which n
LIMITS = {
    "conic": 13,              # 52,728 tetrahedra; the growth is extrapolated
    "newton[pardiso]": 25,    # the direct reference (PARDISO: 375k in ~3 minutes here)
    "elastic[pardiso]": 25,
    "uzawa[direct]": 17,      # G factored and Z = G^-1 N^T formed
    "uzawa-fast[direct]": 17,
}
#: 2D conic series (cylinder_2d, divisions [2m, m]) for the 2D limit
CONIC_2D = [40, 80, 160]
QUICK_CONIC_2D = [20, 40]
KINDS = ["newton[pardiso]", "newton[amg]", "elastic[amg]", "elastic[pardiso]", "uzawa[direct]", "uzawa[amg]",
         "uzawa-fast[direct]", "uzawa-fast[amg]", "conic"]
#: limits of the conic reference asked of the extrapolation: time and memory on this machine
CONIC_TIME_LIMIT_S = 600.0
CONIC_MEMORY_LIMIT_GB = 6.0


def discretization(n: int, dim: int = 3):
    import elastoplast as ep
    from elastoplast.problem.definition import problem_from_dict, read_toml

    if dim == 3:
        d = read_toml(ROOT / "elastoplast" / "data" / "default.toml")
        d["mesh"]["divisions"] = [2 * n, 2 * n, n]
        return ep.discretize(problem_from_dict(d))
    d = read_toml(ROOT / "problems" / "cylinder_2d.toml")
    d["mesh"]["divisions"] = [2 * n, n]
    return ep.discretize(problem_from_dict(d, ROOT / "problems"))


def elastic_amg(disc) -> dict:
    """One elastic solve K u = f (f: the force spread evenly over the contact
    nodes): block assembly, AMG set-up, CG to relative residual 1e-10."""
    from elastoplast.fem.assembly import assemble
    from elastoplast.linalg.amg import AMG, BorderedSystem, one_blas_thread, pcg
    from elastoplast.linalg.blocks import block_layout, bsr, constrain, near_null_space
    from elastoplast.fem.discretize import nondimensionalize

    with one_blas_thread():
        nd, units = nondimensionalize(disc)
        lay = block_layout(nd, units.length)
        A = bsr(lay, constrain(lay, assemble(lay, nd.material.stiffness(nd.dim)), ~lay.free))
        t1 = time.perf_counter()
        amg = AMG(A, near_null_space(lay))
        t2 = time.perf_counter()
        f = lay.embed(nd.N.T @ np.full(nd.n_contact, nd.force / nd.n_contact), nd.free)
        system = BorderedSystem(A, amg)
        x, its, ok = pcg(system.matvec, system.precondition, f, None, 1e-10, 2000)
        t3 = time.perf_counter()
    residual = float(np.linalg.norm(f - A @ x) / np.linalg.norm(f))
    return {"iterations": its, "converged": bool(ok), "relative_residual": residual, "amg_setup_s": t2 - t1,
            "cg_s": t3 - t2, "levels": len(amg.hierarchy.levels),
            "operator_complexity": float(amg.hierarchy.operator_complexity())}


def elastic_pardiso(disc) -> dict:
    """The same elastic solve by PARDISO: K = B^T diag(|T| C) B (upper
    triangle), analysis + factorisation + one solve."""
    import pypardiso
    import scipy.sparse as sp

    from elastoplast.fem.discretize import nondimensionalize

    nd, _ = nondimensionalize(disc)
    K = sp.triu(nd.weighted_gram(nd.material.stiffness(nd.dim)), format="csr")
    K.sort_indices()
    f = nd.N.T @ np.full(nd.n_contact, nd.force / nd.n_contact)
    t1 = time.perf_counter()
    solver = pypardiso.PyPardisoSolver(mtype=2)
    solver.factorize(K)
    t2 = time.perf_counter()
    x = solver.solve(K, f)
    solver.free_memory(everything=True)
    full = K + K.T - sp.diags(K.diagonal())
    return {"iterations": 1, "converged": True, "relative_residual": float(np.linalg.norm(f - full @ x) / np.linalg.norm(f)),
            "factorization_s": t2 - t1}


def run_case(n: int, kind: str, dim: int, store: Path) -> dict:
    """One case in this process; returns its record (peak memory included)."""
    import elastoplast as ep
    from elastoplast.certificate.kkt import energy_norm_sq

    t0 = time.perf_counter()
    disc = discretization(n, dim)
    t_disc = time.perf_counter() - t0
    rec = {"n": n, "dim": dim, "kind": kind, "n_elements": disc.n_elements, "n_free": disc.n_free,
           "n_contact": disc.n_contact, "discretize_s": t_disc}
    w0, c0 = time.perf_counter(), time.process_time()
    if kind == "baseline":
        pass
    elif kind.startswith("elastic"):
        rec.update(elastic_amg(disc) if kind == "elastic[amg]" else elastic_pardiso(disc))
    else:
        method, _, path = kind.partition("[")
        path = path.rstrip("]")
        opts = {}
        if method == "newton":
            opts["linear_solver"] = path
        elif method.startswith("uzawa"):
            opts["factorization"] = "amg" if path == "amg" else "pypardiso"  # the direct path at every size
        sol = ep.solve(disc, method, tol=TOL, **opts) if method != "conic" else ep.solve(disc, "conic")
        rec.update(status=sol.status.value, iterations=sol.iterations, U=sol.U, kkt_worst=sol.kkt.worst,
                   message=sol.message, n_plastic=int(sol.plastic.sum()), n_active=int(sol.active.sum()),
                   timings={k: float(v) for k, v in sol.timings.items()})
        ref_file = store / f"ref_{dim}_{n}.npz"
        if ref_file.exists():
            ref = np.load(ref_file)
            diff = energy_norm_sq(disc, sol.sigma - ref["sigma"], sol.xi - ref["xi"])
            rec["reference"] = str(ref["kind"])
            rec["dU_rel"] = float(abs(sol.U - float(ref["U"])) / abs(float(ref["U"])))
            rec["stress_error_energy"] = float(np.sqrt(diff / energy_norm_sq(disc, ref["sigma"], ref["xi"])))
            rec["same_active"] = bool(np.array_equal(sol.active, ref["active"]))
            rec["same_plastic"] = bool(np.array_equal(sol.plastic, ref["plastic"]))
        elif sol.converged and method == "newton":
            np.savez(ref_file, sigma=sol.sigma, xi=sol.xi, U=sol.U, active=sol.active, plastic=sol.plastic,
                     kind=kind)
    rec["wall_s"] = time.perf_counter() - w0
    rec["cpu_s"] = time.process_time() - c0
    rec["peak_gb"] = peak_memory() / 1e9
    return rec


def spawn(n: int, kind: str, dim: int, store: Path) -> dict:
    """One case in its own process (:func:`run_case`): its record, or the case and the error."""
    t0 = time.perf_counter()
    rec = run_child(__file__, [n, kind, dim, str(store)])
    if "error" in rec:
        rec = {"n": n, "dim": dim, "kind": kind, **rec}
    rec["process_s"] = time.perf_counter() - t0
    return rec


def plan(sizes: list[int], conic_2d: list[int]) -> list[tuple[int, str, int]]:
    cases = []
    for n in sizes:
        for kind in KINDS:
            if n <= LIMITS.get(kind, max(sizes)):
                cases.append((n, kind, 3))
    cases += [(m, "conic", 2) for m in conic_2d]
    return [(4, "baseline", 3)] + cases


def fit_exponent(x, y) -> float | None:
    """Least-squares slope of log y against log x."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return None
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


def summarise(records: list[dict]) -> dict:
    """Growth exponents, the goals at the largest size, the conic extrapolation."""
    out: dict = {"exponents": {}, "goals": {}, "conic_limit": {}}
    base = next((r["peak_gb"] for r in records if r["kind"] == "baseline" and "error" not in r), 0.0)
    out["baseline_gb"] = base
    for kind in KINDS:
        rows = [r for r in records if r["kind"] == kind and r.get("dim") == 3 and "error" not in r
                and r.get("status", "converged") == "converged" and r["n_elements"] >= 20_000]
        if len(rows) >= 2:
            x = [r["n_elements"] for r in rows]
            out["exponents"][kind] = {"wall": fit_exponent(x, [r["wall_s"] for r in rows]),
                                      "cpu": fit_exponent(x, [r["cpu_s"] for r in rows]),
                                      "memory": fit_exponent(x, [r["peak_gb"] - base for r in rows]),
                                      "from_elements": min(x), "to_elements": max(x)}
    big = max((r.get("n_elements", 0) for r in records if r.get("dim") == 3), default=0)
    at = {r["kind"]: r for r in records if r.get("dim") == 3 and "error" not in r and r["n_elements"] == big}
    elastic = [at[k] for k in ("elastic[amg]", "elastic[pardiso]") if k in at]
    if elastic and "newton[amg]" in at:
        best = min(elastic, key=lambda r: r["wall_s"])
        best_cpu = min(r["cpu_s"] for r in elastic)
        g = {"n_elements": big, "elastic_best": best["kind"], "elastic_wall_s": best["wall_s"],
             "elastic_cpu_s": best_cpu}
        for kind in ("newton[amg]", "uzawa[amg]", "uzawa-fast[amg]"):
            if kind in at:
                r = at[kind]
                g[kind] = {"status": r.get("status"), "kkt_worst": r.get("kkt_worst"), "wall_s": r["wall_s"],
                           "cpu_s": r["cpu_s"], "total_wall_s": r["discretize_s"] + r["wall_s"],
                           "peak_gb": r["peak_gb"], "ratio_wall": r["wall_s"] / best["wall_s"],
                           "ratio_cpu": r["cpu_s"] / best_cpu}
        out["goals"] = g
    for dim in (2, 3):
        rows = [r for r in records if r["kind"] == "conic" and r.get("dim") == dim and "error" not in r]
        if len(rows) >= 2:
            x = np.array([r["n_elements"] for r in rows], float)
            pt = fit_exponent(x, [r["wall_s"] for r in rows])
            pm = fit_exponent(x, [r["peak_gb"] - base for r in rows])
            xt = x[-1] * (CONIC_TIME_LIMIT_S / rows[-1]["wall_s"]) ** (1 / pt) if pt and pt > 0 else None
            xm = (x[-1] * ((CONIC_MEMORY_LIMIT_GB - base) / (rows[-1]["peak_gb"] - base)) ** (1 / pm)
                  if pm and pm > 0 else None)
            out["conic_limit"][str(dim)] = {"time_exponent": pt, "memory_exponent": pm,
                                            "elements_at_time_limit": xt, "elements_at_memory_limit": xm,
                                            "measured_up_to": int(x[-1])}
    return out


def report(results: dict) -> str:
    recs = results["records"]
    lines = [f"Default 3D problem, divisions [2n, 2n, n]; every method to KKT <= {TOL:g}; wall and CPU seconds of "
             "the solve after the discretisation; peak memory of the case's own process (mesh included).", "",
             "| tetrahedra | free dofs | case | wall s | CPU s | peak GB | iterations | status / residual | "
             "dU vs ref | stress err vs ref | discretise s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        if r.get("dim") != 3 or r["kind"] == "baseline":
            continue
        if "error" in r:
            lines.append(f"| {r.get('n_elements', '')} | | {r['kind']} | error: {r['error']} | | | | | | | |")
            continue
        status = r.get("status") or f"res {r.get('relative_residual', float('nan')):.1e}"
        if "kkt_worst" in r:
            status += f", KKT {r['kkt_worst']:.1e}"
        du = f"{r['dU_rel']:.1e}" if "dU_rel" in r else ""
        se = f"{r['stress_error_energy']:.1e}" if "stress_error_energy" in r else ""
        lines.append(f"| {r['n_elements']:,} | {r['n_free']:,} | {r['kind']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{r['peak_gb']:.2f} | {r.get('iterations', '')} | {status} | {du} | {se} | "
                     f"{r['discretize_s']:.1f} |")
    s = results["summary"]
    lines += ["", "## Growth exponents (time ~ n^p over the converged sizes from 20k elements)", "",
              f"Memory exponents are of the peak above the baseline process ({s.get('baseline_gb', 0):.2f} GB: "
              "imports and a tiny mesh).", "",
              "| case | p (wall) | p (CPU) | p (memory) | from | to |", "|---|---|---|---|---|---|"]
    for kind, e in s["exponents"].items():
        f = lambda v: "" if v is None else f"{v:.2f}"  # noqa: E731
        lines.append(f"| {kind} | {f(e['wall'])} | {f(e['cpu'])} | {f(e['memory'])} | {e['from_elements']:,} | "
                     f"{e['to_elements']:,} |")
    g = s.get("goals") or {}
    if g:
        lines += ["", f"## Goals at {g['n_elements']:,} tetrahedra (ratios inside this run)", "",
                  f"Best elastic solve: {g['elastic_best']}, {g['elastic_wall_s']:.1f} s wall, "
                  f"{g['elastic_cpu_s']:.1f} s CPU (best of the elastic cases).", "",
                  "| method | status | KKT | wall s | discretise + solve s | CPU s | peak GB | wall / elastic | "
                  "CPU / elastic |", "|---|---|---|---|---|---|---|---|---|"]
        for kind in ("newton[amg]", "uzawa[amg]", "uzawa-fast[amg]"):
            if kind in g:
                r = g[kind]
                lines.append(f"| {kind} | {r['status']} | {r['kkt_worst']:.1e} | {r['wall_s']:.1f} | "
                             f"{r['total_wall_s']:.1f} | {r['cpu_s']:.1f} | {r['peak_gb']:.2f} | "
                             f"{r['ratio_wall']:.1f} | {r['ratio_cpu']:.1f} |")
    cl = s.get("conic_limit") or {}
    if cl:
        lines += ["", "## Conic reference: growth and extrapolated limit", "",
                  f"Extrapolated from the measured sizes to {CONIC_TIME_LIMIT_S:g} s wall or "
                  f"{CONIC_MEMORY_LIMIT_GB:g} GB, whichever comes first.", "",
                  "| dim | measured to | p (time) | p (memory) | elements at time limit | elements at memory limit |",
                  "|---|---|---|---|---|---|"]
        for dim, c in cl.items():
            f = lambda v, fmt: "" if v is None else format(v, fmt)  # noqa: E731
            lines.append(f"| {dim}D | {c['measured_up_to']:,} | {f(c['time_exponent'], '.2f')} | "
                         f"{f(c['memory_exponent'], '.2f')} | {f(c['elements_at_time_limit'], ',.0f')} | "
                         f"{f(c['elements_at_memory_limit'], ',.0f')} |")
        rows2 = [r for r in recs if r["kind"] == "conic"]
        lines += ["", "| dim | elements | wall s | CPU s | peak GB | status |", "|---|---|---|---|---|---|"]
        for r in rows2:
            if "error" not in r:
                lines.append(f"| {r['dim']}D | {r['n_elements']:,} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                             f"{r['peak_gb']:.2f} | {r['status']} |")
    return "\n".join(lines) + "\n"


def plot(results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = [r for r in results["records"] if r.get("dim") == 3 and "error" not in r]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for kind in KINDS:
        rows = sorted((r for r in recs if r["kind"] == kind), key=lambda r: r["n_elements"])
        if not rows:
            continue
        x = [r["n_elements"] for r in rows]
        axes[0].loglog(x, [r["cpu_s"] for r in rows], "o-", label=kind)
        axes[1].loglog(x, [r["peak_gb"] for r in rows], "o-", label=kind)
    axes[0].set(xlabel="tetrahedra", ylabel="CPU s of the solve", title="time")
    axes[1].set(xlabel="tetrahedra", ylabel="peak GB (process)", title="memory")
    axes[0].legend(fontsize=7)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "scaling.png", dpi=120)
    plt.close(fig)


def measure(mode: str, out: Path) -> dict:
    """Every case of the plan, each in its own process; the record (stamped, with its
    report) is written after every case."""
    sizes = QUICK_SIZES if mode == "quick" else SIZES
    cases = plan(sizes, QUICK_CONIC_2D if mode == "quick" else CONIC_2D)
    results = {"tol": TOL, "records": []}
    with tempfile.TemporaryDirectory() as store:
        for n, kind, dim in cases:
            rec = spawn(n, kind, dim, Path(store))
            results["records"].append(rec)
            print(f"{dim}D n={n} {kind}: " + ("error " + str(rec["error"]) if "error" in rec else
                  f"{rec['n_elements']:,} el, {rec['wall_s']:.1f} s wall, {rec['cpu_s']:.1f} s CPU, "
                  f"{rec['peak_gb']:.2f} GB, {rec.get('status', '')} {rec.get('iterations', '')}"), flush=True)
            results["summary"] = summarise(results["records"])
            write_record(out, results, TITLE, report)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "5k and 12k tetrahedra", HERE, TITLE, "scale", measure, report, plot, argv=argv,
                      child=lambda spec: run_case(spec[0], spec[1], spec[2], Path(spec[3])))


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
