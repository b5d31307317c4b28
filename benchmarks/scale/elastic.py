"""The package's linear algebra against an independent elastic solve, and Newton against both (issue 18).

    python benchmarks/scale/elastic.py            # 24k, 118k, 375k, 1.03M tetrahedra (about 15 minutes here)
    python benchmarks/scale/elastic.py --quick    # 5k and 12k tetrahedra, into quick/
    python benchmarks/scale/elastic.py --kinds package,pyamg,newton --sizes 17   # a subset
    python benchmarks/scale/elastic.py --report   # elastic.md again from elastic.json

The default 3D problem with ``[mesh] divisions = [2n, 2n, n]`` (24 n^3 tetrahedra).
Every case runs in its own process (its peak memory is its own); in one run, per size:

* ``elastic[package]``: the package's iterative path on the elastic stiffness, as
  Newton and Uzawa use it: the node-block BSR matrix over every dof with the clamped
  dofs as Dirichlet rows (:mod:`elastoplast.linalg.amg`), its :class:`AMG`
  hierarchy, :func:`pcg` to relative residual 1e-10;
* ``elastic[pyamg]``: an independent solve of the same stiffness written here
  without the package's AMG: ``K`` on the free dofs (assembled by the package,
  ``disc.weighted_gram(C)``), the six rigid-body motions of the free nodes computed
  here, ``pyamg.smoothed_aggregation_solver(K, B=modes, max_coarse=2000)`` with
  pyamg's defaults otherwise (the issue's yardstick), pyamg's own CG to 1e-10;
* ``elastic[petsc]``: CG + GAMG through petsc4py with the rigid-body near-null space
  and Chebyshev/Jacobi smoothing, when petsc4py is importable (else recorded as absent);
* ``newton``, ``uzawa``, ``uzawa-fast``: ``ep.solve(disc, method, tol=1e-8)`` on the
  AMG path, certified.

The right-hand side of the elastic solves is the contact force spread evenly over
the contact nodes. Times are of set-up + solve (after the discretisation), wall and
CPU, with one BLAS thread for every case (``threadpoolctl``; the package does the
same on its AMG path); the machine is shared, so the ratios inside one run and the
CPU times are the figures to read. Writes ``elastic.json`` and ``elastic.md`` (a
side study of benchmarks/scale).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record, write_record  # noqa: E402

HERE = Path(__file__).resolve().parent
TITLE = "Elastic solves against Newton and Uzawa (issue 18)"
STUDY = "elastic"
TOL = 1e-8
CG_RTOL = 1e-10
SIZES = [10, 17, 25, 35]     # 24,000 .. 1,029,000 tetrahedra
QUICK_SIZES = [6, 8]
KINDS = ["elastic[package]", "elastic[pyamg]", "elastic[petsc]", "newton", "uzawa", "uzawa-fast"]
DEFAULT_KINDS = ["elastic[package]", "elastic[pyamg]", "elastic[petsc]", "newton"]
ELASTIC = [k for k in KINDS if k.startswith("elastic")]


def discretization(n: int):
    import elastoplast as ep
    from elastoplast.problem.definition import problem_from_dict, read_toml

    d = read_toml(HERE.parents[1] / "elastoplast" / "data" / "default.toml")
    d["mesh"]["divisions"] = [2 * n, 2 * n, n]
    return ep.discretize(problem_from_dict(d))


def load(disc) -> np.ndarray:
    """The right-hand side on the free dofs: the force spread over the contact nodes."""
    return disc.N.T @ np.full(disc.n_contact, disc.force / disc.n_contact)


def package_solve(disc) -> dict:
    """The package's AMG-CG on its own BSR stiffness (every dof, clamped ones as Dirichlet rows)."""
    from elastoplast.fem.assembly import assemble
    from elastoplast.fem.discretize import nondimensionalize
    from elastoplast.linalg.amg import AMG, BorderedSystem, pcg
    from elastoplast.linalg.blocks import block_layout, bsr, constrain, near_null_space

    nd, units = nondimensionalize(disc)
    lay = block_layout(nd, units.length)
    A = bsr(lay, constrain(lay, assemble(lay, nd.material.stiffness(nd.dim)), ~lay.free))
    f = lay.embed(load(nd), nd.free)
    w0, c0 = time.perf_counter(), time.process_time()
    amg = AMG(A, near_null_space(lay))
    w1 = time.perf_counter()
    system = BorderedSystem(A, amg)
    x, its, ok = pcg(system.matvec, system.precondition, f, None, CG_RTOL, 2000)
    w2, c2 = time.perf_counter(), time.process_time()
    h = amg.hierarchy
    return {"iterations": its, "converged": bool(ok), "relative_residual": float(np.linalg.norm(f - A @ x) / np.linalg.norm(f)),
            "setup_s": w1 - w0, "solve_s": w2 - w1, "wall_s": w2 - w0, "cpu_s": c2 - c0,
            "levels": [int(lv.A.shape[0]) for lv in h.levels], "operator_complexity": float(h.operator_complexity())}


def rigid_body_modes(points: np.ndarray) -> np.ndarray:
    """The six infinitesimal rigid motions of 3D nodes, ``(3 n_nodes, 6)``."""
    x = points - points.mean(axis=0)
    n = len(points)
    modes = np.zeros((n, 3, 6))
    for a in range(3):
        modes[:, a, a] = 1.0
    for j, (a, b) in enumerate([(0, 1), (1, 2), (0, 2)]):
        modes[:, a, 3 + j] = -x[:, b]
        modes[:, b, 3 + j] = x[:, a]
    return modes.reshape(3 * n, 6)


def pyamg_solve(disc) -> dict:
    """The independent yardstick: pyamg's smoothed aggregation, defaults but ``max_coarse=2000``."""
    import pyamg

    K = disc.weighted_gram(disc.material.stiffness(disc.dim)).tocsr()
    f = load(disc)
    w0, c0 = time.perf_counter(), time.process_time()
    B = rigid_body_modes(disc.mesh.points)[disc.free]
    ml = pyamg.smoothed_aggregation_solver(K, B=B, max_coarse=2000)
    w1 = time.perf_counter()
    residuals: list[float] = []
    x = ml.solve(f, tol=CG_RTOL, accel="cg", maxiter=2000, residuals=residuals)
    w2, c2 = time.perf_counter(), time.process_time()
    res = float(np.linalg.norm(f - K @ x) / np.linalg.norm(f))
    return {"iterations": len(residuals) - 1, "converged": res <= 10 * CG_RTOL, "relative_residual": res,
            "setup_s": w1 - w0, "solve_s": w2 - w1, "wall_s": w2 - w0, "cpu_s": c2 - c0,
            "levels": [int(lv.A.shape[0]) for lv in ml.levels], "operator_complexity": float(ml.operator_complexity())}


def petsc_solve(disc) -> dict:
    """CG + GAMG (rigid-body near-null space, Chebyshev/Jacobi smoothing), if petsc4py is there."""
    try:
        from petsc4py import PETSc
    except ImportError:
        return {"absent": "petsc4py is not installed"}
    K = disc.weighted_gram(disc.material.stiffness(disc.dim)).tocsr()
    f = load(disc)
    w0, c0 = time.perf_counter(), time.process_time()
    A = PETSc.Mat().createAIJ(size=K.shape, csr=(K.indptr, K.indices, K.data))
    A.setBlockSize(3)
    modes = rigid_body_modes(disc.mesh.points)[disc.free]
    vecs = [PETSc.Vec().createWithArray(np.ascontiguousarray(m)) for m in modes.T]
    A.setNearNullSpace(PETSc.NullSpace().create(vectors=vecs))
    ksp = PETSc.KSP().create()
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.getPC().setType("gamg")
    ksp.setTolerances(rtol=CG_RTOL, max_it=2000)
    ksp.setFromOptions()
    b, x = A.createVecs()
    b.setArray(f)
    ksp.setUp()
    w1 = time.perf_counter()
    ksp.solve(b, x)
    w2, c2 = time.perf_counter(), time.process_time()
    xa = x.getArray().copy()
    res = float(np.linalg.norm(f - K @ xa) / np.linalg.norm(f))
    return {"iterations": int(ksp.getIterationNumber()), "converged": res <= 10 * CG_RTOL, "relative_residual": res,
            "setup_s": w1 - w0, "solve_s": w2 - w1, "wall_s": w2 - w0, "cpu_s": c2 - c0}


def method_solve(disc, method: str) -> dict:
    import elastoplast as ep

    opts = {"linear_solver": "amg"} if method == "newton" else {"factorization": "amg"}
    w0, c0 = time.perf_counter(), time.process_time()
    sol = ep.solve(disc, method, tol=TOL, **opts)
    w1, c1 = time.perf_counter(), time.process_time()
    rec = {"status": sol.status.value, "converged": sol.converged, "kkt_worst": float(sol.kkt.worst),
           "iterations": sol.iterations, "U": float(sol.U), "wall_s": w1 - w0, "cpu_s": c1 - c0,
           "timings": {k: float(v) for k, v in sol.timings.items()}, "note": sol.message}
    if method == "newton":
        rows = sol.history[1:]
        rec["cg_iterations"] = [r.get("cg_iterations") for r in rows]
        rec["amg_setups"] = int(sum(bool(r.get("amg_setup")) for r in rows))
    return rec


def run_case(n: int, kind: str) -> dict:
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    disc = discretization(n)
    rec = {"n": n, "kind": kind, "n_elements": disc.n_elements, "n_free": disc.n_free,
           "discretize_s": time.perf_counter() - t0}
    with threadpool_limits(limits=1, user_api="blas"):
        if kind == "elastic[package]":
            rec.update(package_solve(disc))
        elif kind == "elastic[pyamg]":
            rec.update(pyamg_solve(disc))
        elif kind == "elastic[petsc]":
            rec.update(petsc_solve(disc))
        else:
            rec.update(method_solve(disc, kind))
    rec["peak_gb"] = peak_memory() / 1e9
    return rec


def fit_exponent(x, y) -> float | None:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(y)
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0]) if ok.sum() >= 2 else None


def summarise(records: list[dict]) -> dict:
    """Growth exponents from 20k elements on, and per size each case's ratio to the best elastic solve."""
    ok = [r for r in records if "error" not in r and "absent" not in r and r.get("converged")]
    out: dict = {"exponents": {}, "ratios": {}}
    for kind in KINDS:
        rows = [r for r in ok if r["kind"] == kind and r["n_elements"] >= 20_000]
        if len(rows) >= 2:
            x = [r["n_elements"] for r in rows]
            out["exponents"][kind] = {"wall": fit_exponent(x, [r["wall_s"] for r in rows]),
                                      "cpu": fit_exponent(x, [r["cpu_s"] for r in rows]),
                                      "from_elements": min(x), "to_elements": max(x)}
    for size in sorted({r["n_elements"] for r in ok}):
        at = {r["kind"]: r for r in ok if r["n_elements"] == size}
        elastic = [at[k] for k in ELASTIC if k in at]
        if not elastic:
            continue
        best_wall = min(elastic, key=lambda r: r["wall_s"])
        best_cpu = min(elastic, key=lambda r: r["cpu_s"])
        out["ratios"][str(size)] = {"best_wall": best_wall["kind"], "best_cpu": best_cpu["kind"],
                                    **{k: {"wall": at[k]["wall_s"] / best_wall["wall_s"],
                                           "cpu": at[k]["cpu_s"] / best_cpu["cpu_s"]} for k in at}}
    return out


def report(results: dict) -> str:
    lines = [f"Default 3D problem, divisions [2n, 2n, n]; elastic solves to relative residual {CG_RTOL:g}, "
             f"methods to KKT <= {TOL:g}; set-up + solve after the discretisation; one BLAS thread.", "",
             "| tetrahedra | free dofs | case | wall s | CPU s | set-up s | peak GB | iterations | result | levels |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["records"]:
        if "error" in r or "absent" in r:
            size = f"{r['n_elements']:,}" if "n_elements" in r else ""
            lines.append(f"| {size} | | {r['kind']} | {r.get('error') or r.get('absent')} | | | | | | |")
            continue
        result = (f"{r['status']}, KKT {r['kkt_worst']:.1e}" if "status" in r
                  else f"res {r['relative_residual']:.1e}")
        its = r["iterations"]
        if "cg_iterations" in r:
            its = f"{its} (CG {sum(c or 0 for c in r['cg_iterations'])}, AMG set-ups {r['amg_setups']})"
        setup = f"{r['setup_s']:.1f}" if "setup_s" in r else ""
        levels = ", ".join(f"{v:,}" for v in r.get("levels", []))
        lines.append(f"| {r['n_elements']:,} | {r['n_free']:,} | {r['kind']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{setup} | {r['peak_gb']:.2f} | {its} | {result} | {levels} |")
    s = results["summary"]
    lines += ["", "## Ratios to the best elastic solve of the same size (wall / CPU)", "",
              "| tetrahedra | best (wall, CPU) | " + " | ".join(KINDS) + " |", "|---|---|" + "---|" * len(KINDS)]
    for size, r in s["ratios"].items():
        cells = [f"{r[k]['wall']:.2f} / {r[k]['cpu']:.2f}" if k in r else "" for k in KINDS]
        lines.append(f"| {int(size):,} | {r['best_wall']}, {r['best_cpu']} | " + " | ".join(cells) + " |")
    lines += ["", "## Growth exponents (time ~ n^p, sizes from 20k elements)", "",
              "| case | p (wall) | p (CPU) | from | to |", "|---|---|---|---|---|"]
    for kind, e in s["exponents"].items():
        f = lambda v: "" if v is None else f"{v:.2f}"  # noqa: E731
        lines.append(f"| {kind} | {f(e['wall'])} | {f(e['cpu'])} | {e['from_elements']:,} | {e['to_elements']:,} |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path, kinds: str | None = None, sizes: str | None = None) -> dict:
    chosen = kinds.split(",") if kinds else DEFAULT_KINDS
    unknown = set(chosen) - set(KINDS)
    if unknown:
        raise SystemExit(f"unknown kinds {sorted(unknown)}; known: {KINDS}")
    ns = [int(v) for v in sizes.split(",")] if sizes else QUICK_SIZES if mode == "quick" else SIZES
    results = {"tol": TOL, "cg_rtol": CG_RTOL, "records": []}
    for n in ns:
        for kind in chosen:
            t0 = time.perf_counter()
            rec = run_child(__file__, [n, kind])
            if "error" in rec:
                rec = {"n": n, "kind": kind, **rec}
            rec["process_s"] = time.perf_counter() - t0
            results["records"].append(rec)
            print(f"n={n} {kind}: " + (str(rec.get("error") or rec.get("absent")) if "error" in rec or "absent" in rec
                  else f"{rec['n_elements']:,} el, {rec['wall_s']:.1f} s wall, {rec['cpu_s']:.1f} s CPU, "
                       f"{rec['peak_gb']:.2f} GB, {rec.get('iterations')} its"), flush=True)
            results["summary"] = summarise(results["records"])
            write_record(out, results, TITLE, report, study=STUDY)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "5k and 12k tetrahedra", HERE, TITLE, "elastic", measure, report, argv=argv,
                      study=STUDY, child=lambda spec: run_case(spec[0], spec[1]),
                      options={"--kinds": {"help": f"comma-separated cases (default {','.join(DEFAULT_KINDS)}; "
                                                   f"known: {','.join(KINDS)})"},
                               "--sizes": {"help": "comma-separated n (divisions [2n, 2n, n])"}})


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
