"""Newton in the meridian plane against one elastic solve of the same mesh (issue 36).

    python benchmarks/scale/axisymmetric.py            # about 10k, 94k, 371k, 1.03M triangles
    python benchmarks/scale/axisymmetric.py --quick    # about 3k triangles, into quick/
    python benchmarks/scale/axisymmetric.py --kinds elastic[pardiso],newton[amg] --sizes 10   # a subset
    python benchmarks/scale/axisymmetric.py --report   # axisymmetric.md again from axisymmetric.json

The problem is ``problems/suite/sphere-axi-2k.toml`` (a sphere R = 10 mm pressed with
3000 N into a steel cylinder 20 x 20 mm, H = E/20, a developed plastic zone) on graded gmsh
meshes of the meridian plane, ``h_contact`` 0.01 mm and ``h_far`` 1/n mm. (The tensor-product
grid of ``problems/sphere_axisymmetric.toml``, grading 3, is no scale family: its cells
stretch with n, 1.5e6 : 1 at divisions [708, 708], refused by the mesh checks.) Every case runs
in its own process (its peak memory, VmHWM, is its own: mesh and discretisation
included); per size:

* ``elastic[pyamg]``: the yardstick, an elastic solve written here without the
  package's AMG, as ``elastic.py`` does in 3D: ``K = disc.weighted_gram(C)`` on the free
  dofs (the ring weights w_T and the hoop row are in it), the near-null space computed
  here (the meridian plane's two translations and in-plane rotation of the nodes),
  ``pyamg.smoothed_aggregation_solver`` on 2 x 2 node blocks with strength theta = 0.02
  and no candidate improvement, pyamg's defaults otherwise (``pyamg_solve`` says why),
  pyamg's CG to relative residual 1e-10 (on the stretched tensor-product grid above it
  converged at 10,368 triangles but not at 51,200 in 3000 iterations, and newton took 47
  (direct) and 69 (AMG) steps there at 51,200: the graded gmsh meshes are the ones to time);
* ``elastic[pardiso]``: the same ``K`` on the free dofs solved by pypardiso (MKL PARDISO),
  a second independent yardstick: in 2D a sparse direct solve is cheap;
* ``elastic[package]``: the package's AMG-CG on its own BSR stiffness (``elastic.py``'s
  ``package_solve``);
* ``newton[amg]``, ``newton[direct]``: ``ep.solve(disc, "newton", tol=1e-8,
  linear_solver="amg" | "pardiso")``, certified.

The right-hand side of the elastic solves is the force spread over the contact nodes.
Times are of set-up + solve after the discretisation, wall and CPU, one BLAS thread.
Writes ``axisymmetric.json`` and ``axisymmetric.md`` (a side study of benchmarks/scale).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
from harness import peak_memory, run_child, run_record, write_record  # noqa: E402
from elastic import fit_exponent, load, package_solve  # noqa: E402

TITLE = "Newton in the meridian plane against one elastic solve (issue 36)"
STUDY = "axisymmetric"
TOL = 1e-8
CG_RTOL = 1e-10
SIZES = [3, 10, 20, 33]          # h_far 1/n: about 10k, 94k, 371k, 1.03M triangles
QUICK_SIZES = [2]
KINDS = ["elastic[pyamg]", "elastic[pardiso]", "elastic[package]", "newton[amg]", "newton[direct]"]
DEFAULT_KINDS = KINDS
INDEPENDENT = ("elastic[pyamg]", "elastic[pardiso]")   # the elastic solves written without the package's AMG


def discretization(n: int):
    """``problems/suite/sphere-axi-2k.toml`` with ``h_contact`` 0.01 and ``h_far`` 1 / n (the
    far field dominates the count; the graded generator's own estimate refuses a finer
    ``h_contact`` at a million triangles)."""
    import elastoplast as ep

    suite = HERE.parents[1] / "problems" / "suite"
    d = ep.read_toml(suite / "sphere-axi-2k.toml")
    d["mesh"].update(h_contact=0.01, h_far=1.0 / n)
    return ep.discretize(ep.problem_from_dict(d, base_dir=suite))


def meridian_modes(points: np.ndarray) -> np.ndarray:
    """The two translations and the in-plane rotation of 2D nodes, ``(2 n_nodes, 3)``."""
    x = points - points.mean(axis=0)
    n = len(points)
    modes = np.zeros((n, 2, 3))
    modes[:, 0, 0] = 1.0
    modes[:, 1, 1] = 1.0
    modes[:, 0, 2], modes[:, 1, 2] = -x[:, 1], x[:, 0]
    return modes.reshape(2 * n, 3)


def free_embedding(disc):
    """``(E, fixed)``: the embedding of the free dofs into every dof and the fixed dofs' mask."""
    n = disc.mesh.n_nodes * disc.dim
    E = sp.csr_matrix((np.ones(disc.n_free), (disc.free, np.arange(disc.n_free))), shape=(n, disc.n_free))
    fixed = np.ones(n)
    fixed[disc.free] = 0.0
    return E, fixed


def pyamg_solve(disc) -> dict:
    """The independent yardstick: pyamg's smoothed aggregation on node blocks.

    ``K`` is embedded into every dof with identity rows (times K's mean diagonal) at the
    fixed ones, as 2 x 2 blocks: on the free dofs alone the axis nodes hold one dof, the
    blocks break, and pyamg's scalar aggregation did not converge in 3000 iterations at
    10k triangles (of the stretched tensor-product grid; measured before the gmsh meshes). pyamg's defaults but two: strength theta = 0.02 (with theta = 0, its
    default, every connection is strong, the aggregates of the stretched cells of the
    tensor-product grid are poor: no convergence in 3000 iterations at 10k triangles either),
    and no improvement of the candidates (its default four Gauss-Seidel sweeps over B:
    also 3000 iterations)."""
    import pyamg

    K = disc.weighted_gram(disc.material.stiffness(disc.dim)).tocsr()
    f = load(disc)
    w0, c0 = time.perf_counter(), time.process_time()
    E, fixed = free_embedding(disc)
    A = (E @ K @ E.T + sp.diags(fixed * K.diagonal().mean())).tobsr(blocksize=(disc.dim, disc.dim))
    ml = pyamg.smoothed_aggregation_solver(A, B=meridian_modes(disc.mesh.points),
                                           strength=("symmetric", {"theta": 0.02}), improve_candidates=None)
    w1 = time.perf_counter()
    residuals: list[float] = []
    x = E.T @ ml.solve(E @ f, tol=CG_RTOL, accel="cg", maxiter=3000, residuals=residuals)
    w2, c2 = time.perf_counter(), time.process_time()
    res = float(np.linalg.norm(f - K @ x) / np.linalg.norm(f))
    return {"iterations": len(residuals) - 1, "converged": res <= 10 * CG_RTOL, "relative_residual": res,
            "setup_s": w1 - w0, "solve_s": w2 - w1, "wall_s": w2 - w0, "cpu_s": c2 - c0,
            "levels": [int(lv.A.shape[0]) for lv in ml.levels], "operator_complexity": float(ml.operator_complexity())}


def pardiso_solve(disc) -> dict:
    """A direct elastic solve of the same ``K`` (free dofs) by pypardiso (MKL PARDISO)."""
    import pypardiso

    K = disc.weighted_gram(disc.material.stiffness(disc.dim)).tocsr()
    f = load(disc)
    w0, c0 = time.perf_counter(), time.process_time()
    x = pypardiso.spsolve(K, f)
    w1, c1 = time.perf_counter(), time.process_time()
    res = float(np.linalg.norm(f - K @ x) / np.linalg.norm(f))
    return {"iterations": 1, "converged": res <= 10 * CG_RTOL, "relative_residual": res,
            "wall_s": w1 - w0, "cpu_s": c1 - c0}


def newton_solve(disc, linear_solver: str) -> dict:
    import warnings

    import elastoplast as ep

    w0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = ep.solve(disc, "newton", tol=TOL, linear_solver=linear_solver, progress=False)
    w1, c1 = time.perf_counter(), time.process_time()
    rows = sol.history[1:]
    rec = {"status": sol.status.value, "converged": sol.converged, "kkt_worst": float(sol.kkt.worst),
           "iterations": sol.iterations, "U": float(sol.U), "wall_s": w1 - w0, "cpu_s": c1 - c0,
           "timings": {k: float(v) for k, v in sol.timings.items()}, "note": sol.message,
           "warnings": sorted({str(w.message) for w in caught})}
    if linear_solver == "amg":
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
        if kind == "elastic[pyamg]":
            rec.update(pyamg_solve(disc))
        elif kind == "elastic[pardiso]":
            rec.update(pardiso_solve(disc))
        elif kind == "elastic[package]":
            rec.update(package_solve(disc))
        else:
            rec.update(newton_solve(disc, "amg" if kind == "newton[amg]" else "pardiso"))
    rec["peak_gb"] = peak_memory() / 1e9
    return rec


def summarise(records: list[dict]) -> dict:
    """Per size each case's ratio to the best independent elastic solve of that size
    (elastic[pyamg] or elastic[pardiso]; wall and CPU apart); growth exponents from 20k
    triangles on."""
    ok = [r for r in records if "error" not in r and r.get("converged")]
    out: dict = {"ratios": {}, "exponents": {}}
    for size in sorted({r["n_elements"] for r in ok}):
        at = {r["kind"]: r for r in ok if r["n_elements"] == size}
        elastic = [r for k, r in at.items() if k in INDEPENDENT]
        if elastic:
            wall = min(r["wall_s"] for r in elastic)
            cpu = min(r["cpu_s"] for r in elastic)
            out["ratios"][str(size)] = {k: {"wall": r["wall_s"] / wall, "cpu": r["cpu_s"] / cpu} for k, r in at.items()}
    for kind in KINDS:
        rows = [r for r in ok if r["kind"] == kind and r["n_elements"] >= 20_000]
        if len(rows) >= 2:
            x = [r["n_elements"] for r in rows]
            out["exponents"][kind] = {"cpu": fit_exponent(x, [r["cpu_s"] for r in rows]),
                                      "from_elements": min(x), "to_elements": max(x)}
    return out


def report(results: dict) -> str:
    lines = [f"`problems/suite/sphere-axi-2k.toml`, h_contact 0.01, h_far 1/n; elastic solves to relative residual "
             f"{CG_RTOL:g}, newton to KKT <= {TOL:g}; set-up + solve after the discretisation; one BLAS thread.", "",
             "| triangles | free dofs | case | wall s | CPU s | peak GB | iterations | result | ratio to the best independent elastic solve (wall / CPU) |",
             "|---|---|---|---|---|---|---|---|---|"]
    summary = summarise(results["records"])  # again from the records: --report renders a recorded run anew
    ratios = summary["ratios"]
    for r in results["records"]:
        if "error" in r:
            lines.append(f"| {r.get('n_elements', '')} | | {r['kind']} | {r['error']} | | | | | |")
            continue
        result = (f"{r['status']}, KKT {r['kkt_worst']:.1e}" if "status" in r
                  else f"res {r['relative_residual']:.1e}" + (f", levels {', '.join(f'{v:,}' for v in r['levels'])}"
                                                          if r.get("levels") else ""))
        if r.get("warnings"):
            result += "; warned: " + "; ".join(r["warnings"])
        its = r["iterations"]
        if "cg_iterations" in r:
            its = f"{its} (CG {sum(c or 0 for c in r['cg_iterations'])}, AMG set-ups {r['amg_setups']})"
        q = ratios.get(str(r["n_elements"]), {}).get(r["kind"])
        ratio = f"{q['wall']:.2f} / {q['cpu']:.2f}" if q else ""
        lines.append(f"| {r['n_elements']:,} | {r['n_free']:,} | {r['kind']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{r['peak_gb']:.2f} | {its} | {result} | {ratio} |")
    exps = summary["exponents"]
    if exps:
        lines += ["", "Growth exponents (CPU time ~ n^p, from 20k triangles):", "",
                  "| case | p | from | to |", "|---|---|---|---|"]
        for kind, e in exps.items():
            lines.append(f"| {kind} | {e['cpu']:.2f} | {e['from_elements']:,} | {e['to_elements']:,} |")
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
            print(f"n={n} {kind}: " + (str(rec["error"]) if "error" in rec
                  else f"{rec['n_elements']:,} el, {rec['wall_s']:.1f} s wall, {rec['cpu_s']:.1f} s CPU, "
                       f"{rec['peak_gb']:.2f} GB, {rec.get('iterations')} its"), flush=True)
            results["summary"] = summarise(results["records"])
            write_record(out, results, TITLE, report, study=STUDY)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "about 3k triangles", HERE, TITLE, "axisymmetric", measure, report, argv=argv,
                      study=STUDY, child=lambda spec: run_case(spec[0], spec[1]),
                      options={"--kinds": {"help": f"comma-separated cases (default {','.join(DEFAULT_KINDS)}; "
                                                   f"known: {','.join(KINDS)})"},
                               "--sizes": {"help": "comma-separated n (h_far = 1/n)"}})


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
