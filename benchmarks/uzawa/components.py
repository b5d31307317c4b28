"""Measure the two building blocks of Uzawa's step (ii), to choose them.

* the sparse factorisation of the metric G = sum |T| B^T B: for each backend of
  ``elastoplast.solvers.uzawa.FACTORIZATIONS``, factor time, mean time of one solve,
  time of the n_contact-column solve Z = G^{-1} N^T, relative residual;
* the contact QP ``min 1/2 lam S lam + g lam, lam >= 0``: the QPs of a real Uzawa
  run are recorded and solved again by the warm-started active-set method, the
  same from zero, Lawson-Hanson NNLS (scipy) and OSQP (warm-started, polished):
  mean time per QP and the worst KKT violation relative to |g|.

Usage::

    python benchmarks/uzawa/components.py            # components.json and components.md in this folder
    python benchmarks/uzawa/components.py --quick    # small cases, into quick/ (not committed)
    python benchmarks/uzawa/components.py --report   # only components.md again, from components.json
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

import elastoplast.solvers.contact as contact
from common import family
from elastoplast.solvers.uzawa import UzawaOptions, solve_uzawa
from elastoplast.solvers.contact import nnls_fallback, solve_contact_qp
from elastoplast.linalg.direct import FACTORIZATIONS
from elastoplast.solvers.uzawa import metric_matrix

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
TITLE = "Uzawa's step (ii): factorisation of G and the contact QP"

CASES = [("cylinder_2d", [160, 80]), ("sphere_block_3d", [16, 16, 8]), ("sphere_block_3d", [26, 26, 13])]
QUICK = [("cylinder_2d", [80, 40]), ("sphere_block_3d", [12, 12, 6])]


def measure(disc, name: str, repeats: int = 20) -> dict:
    G = metric_matrix(disc)
    t0 = time.perf_counter()
    solve = FACTORIZATIONS[name](G)
    t_factor = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    b = rng.standard_normal(G.shape[0])
    solve(b)
    t0 = time.perf_counter()
    for _ in range(repeats):
        x = solve(b)
    t_solve = (time.perf_counter() - t0) / repeats
    t0 = time.perf_counter()
    solve(disc.N.T.toarray())
    t_multi = time.perf_counter() - t0
    return {"backend": name, "factor_s": t_factor, "solve_s": t_solve, "contact_columns_s": t_multi,
            "residual": float(np.linalg.norm(G @ x - b) / np.linalg.norm(b))}


def record_qps(disc) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
    """The (S, g, warm start) of every contact QP of one Uzawa run.

    The QP in S exists on the direct path only: from ``UZAWA_AMG_FROM_ELEMENTS``
    elements on, "auto" projects by a primal-dual active set on AMG-CG face solves
    and forms no S. The run therefore factors G with SuperLU (always installed; the
    QPs do not depend on the factorisation beyond round-off)."""
    seen = []
    exact = contact.solve_contact_qp

    def spy(S, g, lam0=None, max_iter=None):
        seen.append((S, g.copy(), None if lam0 is None else lam0.copy()))
        return exact(S, g, lam0, max_iter)

    contact.solve_contact_qp = spy  # as Uzawa's contact step calls it
    try:
        solve_uzawa(disc, UzawaOptions(tol=1e-6, factorization="splu"))
    finally:
        contact.solve_contact_qp = exact
    return seen


def kkt_violation(S, g, lam) -> float:
    w = S @ lam + g
    return float(max(-lam.min(), -w.min(), np.abs(lam * w).max() / max(np.abs(lam).max(), 1e-300)) / np.abs(g).max())


def qp_methods():
    import osqp
    import scipy.sparse as sp

    def osqp_solver(S, g, lam0):
        n = g.size
        m = osqp.OSQP()
        m.setup(sp.csc_matrix(np.triu(S)), g, sp.eye(n, format="csc"), np.zeros(n), np.full(n, np.inf),
                eps_abs=1e-10, eps_rel=1e-10, polishing=True, verbose=False, max_iter=20000)
        if lam0 is not None:
            m.warm_start(x=lam0)
        return m.solve().x

    return {
        "active-set (warm)": lambda S, g, lam0: solve_contact_qp(S, g, lam0),
        "active-set (cold)": lambda S, g, lam0: solve_contact_qp(S, g),
        "nnls (scipy)": lambda S, g, lam0: nnls_fallback(S, g),
        "osqp (warm, polished)": osqp_solver,
    }


def measure_qps(disc) -> list[dict]:
    qps = record_qps(disc)
    rows = []
    for name, fn in qp_methods().items():
        t0 = time.perf_counter()
        worst = max(kkt_violation(S, g, fn(S, g, lam0)) for S, g, lam0 in qps)
        rows.append({"qp_method": name, "n_qps": len(qps), "n_contact": disc.n_contact,
                     "mean_s": (time.perf_counter() - t0) / len(qps), "worst_kkt_violation": worst})
        print(json.dumps(rows[-1]))
    return rows


def markdown(data: dict) -> str:
    """The report's body: both tables of ``data``."""
    out = ["Factorisation of G: factor time, one solve, the n_contact-column solve Z = G^-1 N^T, relative residual.",
           "", "| problem | elements | rows of G | backend | factor s | solve s | Z s | residual |",
           "|---|---|---|---|---|---|---|---|"]
    for r in data["factorizations"]:
        out.append(f"| {r['problem']} | {r['n_elements']} | {r['n_free']} | {r['backend']} | {r['factor_s']:.3g} "
                   f"| {r['solve_s']:.3g} | {r['contact_columns_s']:.3g} | {r['residual']:.1e} |")
    out += ["", "Contact QP, replayed from one Uzawa run on the largest case: mean time per QP and worst KKT "
            "violation relative to max|g|.", "", "| method | QPs | contact nodes | mean s | worst KKT violation |",
            "|---|---|---|---|---|"]
    for r in data["contact_qp"]:
        out.append(f"| {r['qp_method']} | {r['n_qps']} | {r['n_contact']} | {r['mean_s']:.2g} | {r['worst_kkt_violation']:.1e} |")
    return "\n".join(out) + "\n"


def measure_all(mode: str, out: Path) -> dict:
    cases = QUICK if mode == "quick" else CASES
    rows = []
    for name, div in cases:
        disc = family(name, div)
        for backend in FACTORIZATIONS:
            row = {"problem": name, "divisions": div, "n_elements": disc.n_elements, "n_free": disc.n_free,
                   "n_contact": disc.n_contact, **measure(disc, backend)}
            rows.append(row)
            print(json.dumps(row))
    qps = measure_qps(family(*cases[-1]))
    return {"quick": mode == "quick", "factorizations": rows, "contact_qp": qps}


def main(argv=None) -> int:
    return run_record(__doc__, "small cases", HERE, TITLE, "Uzawa components study", measure_all, markdown, argv=argv,
                      study="components")


if __name__ == "__main__":
    sys.exit(main())
