"""Which linear solver for Newton's systems: one elastic stiffness K of the 3D sphere.

    python benchmarks/methods/factorizations.py [NX NY NZ]    # default 24 24 12 (41k tetrahedra)
    python benchmarks/methods/factorizations.py --quick      # 8 8 4, into quick/ (not committed)
    python benchmarks/methods/factorizations.py --report     # only factorizations.md again

Times, for the same K (nondimensionalised), PARDISO (SPD, upper triangle:
analysis, then numerical factorisation alone, as Newton repeats it), SciPy's
SuperLU (COLAMD), cholespy, QDLDL, and pyamg's smoothed aggregation as a CG
preconditioner (rigid-body modes as near-null space), each to a relative
residual of 1e-10. Writes ``factorizations.json`` and ``factorizations.md`` beside
this file (``--out`` to change).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import elastoplast as ep
from elastoplast.fem.assembly import rigid_motions
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.problem.definition import problem_from_dict, read_toml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
TITLE = "Linear solvers for Newton's systems: one elastic stiffness K of the 3D sphere"
DEFAULT, QUICK = [24, 24, 12], [8, 8, 4]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def markdown(out: dict) -> str:
    """The report's body: one row per solver, its phases and residual."""
    phases = ["analysis_s", "setup_s", "factorization_s", "solve_s"]
    lines = [f"K: {out['n_elements']} tetrahedra, {out['n_dofs']} dofs, {out['nnz']} nonzeros; right-hand side "
             "random (seed 0); times in seconds.", "",
             "| solver | analysis | setup | factorisation | solve | total | CG iterations | residual |",
             "|---|---|---|---|---|---|---|---|"]
    for name, row in out["solvers"].items():
        cells = [f"{row[k]:.3g}" if k in row else "-" for k in phases]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sum(row.get(k, 0.0) for k in phases):.3g} "
                     f"| {row.get('cg_iterations', '-')} | {row['residual']:.1e} |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out_dir: Path, divisions: list[int]) -> dict:
    div = divisions[:3] or (QUICK if mode == "quick" else DEFAULT)
    d = read_toml(HERE.parents[1] / "problems" / "sphere_block_3d.toml")
    d["mesh"]["divisions"] = div
    disc = ep.discretize(problem_from_dict(d, HERE.parents[1] / "problems"))
    nd, _ = nondimensionalize(disc)
    K = nd.weighted_gram(nd.material.stiffness(3))
    b = np.random.default_rng(0).standard_normal(K.shape[0])
    res = lambda x: float(np.linalg.norm(K @ x - b) / np.linalg.norm(b))  # noqa: E731
    out = {"divisions": div, "n_elements": disc.n_elements, "n_dofs": K.shape[0], "nnz": K.nnz, "solvers": {}}

    import pypardiso

    Ku = sp.triu(K, format="csr")
    Ku.sort_indices()
    ps = pypardiso.PyPardisoSolver(mtype=2)
    ps.set_phase(11)
    _, t_an = timed(lambda: ps._call_pardiso(Ku, np.zeros_like(b)))
    ps.set_phase(22)
    _, t_fa = timed(lambda: ps._call_pardiso(Ku, np.zeros_like(b)))
    ps.set_phase(33)
    x, t_so = timed(lambda: ps._call_pardiso(Ku, b))
    out["solvers"]["pardiso"] = {"analysis_s": t_an, "factorization_s": t_fa, "solve_s": t_so, "residual": res(x)}

    lu, t = timed(lambda: sla.splu(K.tocsc()))
    x, t_so = timed(lambda: lu.solve(b))
    out["solvers"]["splu_colamd"] = {"factorization_s": t, "solve_s": t_so, "residual": res(x)}

    from cholespy import CholeskySolverD, MatrixType

    Kc = K.tocoo()
    cs, t = timed(lambda: CholeskySolverD(K.shape[0], Kc.row.astype(np.int32), Kc.col.astype(np.int32), Kc.data,
                                          MatrixType.COO))
    x = np.zeros_like(b)
    _, t_so = timed(lambda: cs.solve(b, x))
    out["solvers"]["cholespy"] = {"factorization_s": t, "solve_s": t_so, "residual": res(x)}

    import qdldl

    q, t = timed(lambda: qdldl.Solver(sp.triu(K, format="csc")))
    x, t_so = timed(lambda: q.solve(b))
    out["solvers"]["qdldl"] = {"factorization_s": t, "solve_s": t_so, "residual": res(x)}

    import pyamg

    from elastoplast.linalg.amg import one_blas_thread

    modes = rigid_motions(disc.mesh.points)[disc.free]
    # the settings of elastoplast.linalg.amg.AMG: pyamg's default coarse solver (a pseudo-inverse)
    # recomputes an SVD at every cycle, which made this row 8x slower than the package's path
    ml, t = timed(lambda: pyamg.smoothed_aggregation_solver(K, B=modes, max_coarse=500, coarse_solver="splu",
                                                            improve_candidates=None))
    hist: list[float] = []
    with one_blas_thread():  # as the package's Krylov loops run (linalg.one_blas_thread: two spin-waiting threads cost 3.5x CPU)
        x, t_so = timed(lambda: ml.solve(b, tol=1e-10, accel="cg", residuals=hist, maxiter=1000))
    out["solvers"]["pyamg_sa_cg"] = {"setup_s": t, "solve_s": t_so, "cg_iterations": len(hist) - 1, "residual": res(x)}

    for name, row in out["solvers"].items():
        print(name, {k: round(v, 3) if isinstance(v, float) and v > 1e-3 else v for k, v in row.items()})
    return out


def main(argv=None) -> int:
    divisions = {"nargs": "*", "type": int, "help": f"mesh divisions NX NY NZ (default {DEFAULT})"}
    return run_record(__doc__, f"divisions {QUICK}", HERE, TITLE, "factorizations study", measure, markdown,
                      argv=argv, study="factorizations", options={"divisions": divisions})


if __name__ == "__main__":
    sys.exit(main())
