"""One adapter for the conic solvers: Clarabel and SCS on data ``(P, q, A, b, cones)``.

Every conic program of the package (the stress form (S), the lower-bound programs, the
kinematic limit-load program) is handed over in Clarabel's convention: minimise
``1/2 x'Px + q'x`` subject to ``A x + s = b``, ``s`` in a product of cones, with the KKT
condition ``P x + q + A'z = 0``. SCS uses the same convention. The answer comes back as
one :class:`ConicAnswer`, in the solver's words (``raw``) and in the package's
(:class:`~elastoplast.certificate.solution.Status`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from elastoplast.certificate.solution import Status
from elastoplast.fem.stress_form import AffineRows

CLARABEL_STATUS = {
    "Solved": Status.CONVERGED,
    "AlmostSolved": Status.CONVERGED,
    "PrimalInfeasible": Status.INFEASIBLE,
    "AlmostPrimalInfeasible": Status.INFEASIBLE,
    # every program here minimises a convex quadratic bounded below: a certificate of
    # dual infeasibility (an unbounded objective) is numerical failure
    "DualInfeasible": Status.FAILED,
    "AlmostDualInfeasible": Status.FAILED,
    "MaxIterations": Status.MAX_ITERATIONS,
    "MaxTime": Status.TIME_LIMIT,
}

#: SCS's ``status_val`` (scs/include/glbopts.h); 2 is "solved inaccurate", what SCS
#: returns at its iteration or time limit with a usable point
SCS_STATUS = {1: Status.CONVERGED, 2: Status.MAX_ITERATIONS, -2: Status.INFEASIBLE, -7: Status.INFEASIBLE}

_INFEASIBLE = ("PrimalInfeasible", "AlmostPrimalInfeasible", "infeasible", "infeasible_inaccurate")
_UNBOUNDED = ("DualInfeasible", "AlmostDualInfeasible", "unbounded", "unbounded_inaccurate")


@dataclass(frozen=True)
class ConicAnswer:
    """A conic solver's answer: primal ``x``, dual ``z``, slack ``s``.

    ``infeasible`` (no feasible point) and ``unbounded`` (no bound below) are the
    solver's certificates, whichever solver gave them.
    """

    solver: str
    status: Status
    raw: str
    x: np.ndarray
    z: np.ndarray
    s: np.ndarray
    objective: float
    iterations: int

    @property
    def infeasible(self) -> bool:
        return self.raw in _INFEASIBLE

    @property
    def unbounded(self) -> bool:
        return self.raw in _UNBOUNDED

    @property
    def label(self) -> str:
        return f"{'SCS' if self.solver == 'scs' else 'Clarabel'}: {self.raw}"


def clarabel_rows(groups: list[AffineRows], n_cols: int) -> tuple[list[sp.csc_matrix], list[np.ndarray], list]:
    """Clarabel's ``s = b - A x`` in its cones from the neutral row groups of
    :mod:`elastoplast.fem.stress_form` (``g = G x + h`` in a cone): ``(blocks, rhs, cones)``,
    one block of A and of b per run of consecutive zero-cone groups and per other group.
    A zero cone is a subspace and is taken as ``s = -g`` (``A = G``, ``b = -h``: the
    multipliers of equilibrium are then the displacements, of the force balance U);
    every other cone as ``s = g`` (``A = -G``, ``b = h``)."""
    import clarabel

    blocks, rhs, cones, run = [], [], [], []

    def close_run() -> None:
        if run:
            offsets = np.cumsum([0] + [g.n_rows for g in run])
            rows = np.concatenate([o + g.row for o, g in zip(offsets, run)])
            cols = np.concatenate([g.col for g in run])
            blocks.append(sp.csc_matrix((np.concatenate([g.val for g in run]), (rows, cols)), shape=(offsets[-1], n_cols)))
            b = np.zeros(offsets[-1])
            for o, g in zip(offsets, run):
                b[o + g.h_rows] = -g.h_vals
            rhs.append(b)
            cones.append(clarabel.ZeroConeT(int(offsets[-1])))
            run.clear()

    for g in groups:
        if g.cone == "zero":
            run.append(g)
            continue
        close_run()
        # 0 - G: -G, its explicit zeros (blocks kron stores densely) kept +0.0
        blocks.append(sp.csc_matrix((0.0 - g.val, (g.row, g.col)), shape=(g.n_rows, n_cols)))
        rhs.append(g.h())
        if g.cone == "nonnegative":
            cones.append(clarabel.NonnegativeConeT(g.n_rows))
        else:
            cones += [clarabel.SecondOrderConeT(g.cone_size)] * (g.n_rows // g.cone_size)
    close_run()
    return blocks, rhs, cones


def clarabel_settings(options, linear_solver: str = "qdldl"):
    """Clarabel's settings from options with ``verbose``, ``max_iter``, ``time_limit`` and ``ip_tol``."""
    import clarabel

    s = clarabel.DefaultSettings()
    s.verbose = options.verbose
    s.max_iter = options.max_iter
    s.time_limit = float("inf") if options.time_limit is None else options.time_limit
    s.tol_gap_abs = options.ip_tol
    s.tol_gap_rel = options.ip_tol
    s.tol_feas = options.ip_tol
    s.tol_ktratio = min(1e-6, options.ip_tol)
    s.direct_solve_method = linear_solver
    return s


def solve_clarabel(P, q, A, b, cones, settings) -> ConicAnswer:
    """Clarabel's interior point on ``(P, q, A, b, cones)`` with ``settings`` (:func:`clarabel_settings`)."""
    import clarabel

    res = clarabel.DefaultSolver(P, q, A, b, cones, settings).solve()
    raw = str(res.status).split(".")[-1]
    return ConicAnswer("clarabel", CLARABEL_STATUS.get(raw, Status.FAILED), raw, np.asarray(res.x),
                       np.asarray(res.z), np.asarray(res.s), float(res.obj_val), int(res.iterations))


def scs_cones(cones: list) -> dict:
    """Clarabel's cone list as SCS's cone dictionary (same row order: zero, nonnegative, SOC)."""
    z = sum(c.dim for c in cones if type(c).__name__ == "ZeroConeT")
    nn = sum(c.dim for c in cones if type(c).__name__ == "NonnegativeConeT")
    q = [c.dim for c in cones if type(c).__name__ == "SecondOrderConeT"]
    if len(cones) != (z > 0) + (nn > 0) + len(q):
        raise ValueError("cones other than zero, nonnegative and second-order")
    return {"z": z, "l": nn, "q": q}


def solve_scs(P, q, A, b, cones, eps: float, max_iters: int, verbose: bool = False,
              time_limit: float | None = None) -> ConicAnswer:
    """SCS (O'Donoghue et al. 2016, 2021) on the same data as :func:`solve_clarabel`.

    SCS is Douglas-Rachford splitting on the homogeneous self-dual embedding: each
    iteration solves one linear system with a matrix factored once and projects onto
    the cones in closed form, with Anderson acceleration. Its residuals are of the
    size of ``eps``.
    """
    import scs

    settings = dict(eps_abs=eps, eps_rel=eps, max_iters=max_iters, verbose=verbose)
    if time_limit is not None:
        settings["time_limit_secs"] = float(time_limit)
    data = {"P": sp.triu(P, format="csc"), "A": sp.csc_matrix(A), "b": b, "c": q}
    res = scs.SCS(data, scs_cones(cones), **settings).solve()
    info = res["info"]
    return ConicAnswer("scs", SCS_STATUS.get(int(info["status_val"]), Status.FAILED), str(info["status"]),
                       np.array(res["x"], dtype=float), np.asarray(res["y"]), np.asarray(res["s"]),
                       float(info["pobj"]), int(info["iter"]))
