"""Uzawa's step (ii): the projection onto K_h in the metric G, for every contact set.

Direct (:class:`DirectProjection`: G factored once, the contact QP in the Schur complement) or
iterative (:class:`IterativeProjection`: AMG-preconditioned CG on G, the contact set by active sets)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization
from elastoplast.linalg.direct import Solve, factorize_spd


@dataclass(frozen=True)
class ContactOperators:
    """What step (ii) needs besides G^{-1}: ``Z = G^{-1} N^T`` (free dofs x contact
    nodes), the weight ``w`` of the rigid body's displacement in the metric
    ``|v|_G^2 + w V^2`` and the Schur complement ``S = N G^{-1} N^T + 1 1^T / w``
    of the dual QP."""

    Z: np.ndarray
    S: np.ndarray
    weight: float = 1.0


#: automatic weight of V: ``1 / w = RIGID_WEIGHT_FACTOR * trace(N G^{-1} N^T)``
RIGID_WEIGHT_FACTOR = 10.0


def contact_operators(N: sp.spmatrix, solve: Solve, weight: float | None = None) -> ContactOperators:
    """``Z = G^{-1} N^T`` (one solve with n_contact right-hand sides) and ``S``.

    The paper writes the metric as ``|eps(v)|^2 + V^2``; in 3D the two terms
    carry different units (length^3 against length^2), so the weight of V is
    a choice. ``weight=None`` takes ``1 / w = 10 trace(N G^{-1} N^T)``: V then
    costs nothing next to the contact displacements, which the measured sweep
    (benchmarks/uzawa/weight.md) found fastest, on a plateau reached a decade
    earlier; a weight of 1 in the problem's units is the paper's literal metric.
    """
    Z = solve(N.T.toarray())
    Z = Z.reshape(N.shape[1], N.shape[0])
    M = N @ Z
    M = 0.5 * (M + M.T)
    if weight is None:
        weight = 1.0 / (RIGID_WEIGHT_FACTOR * max(np.trace(M), np.finfo(float).tiny))
    if not (np.isfinite(weight) and weight > 0):
        raise InputError("rigid_weight", f"must be a number > 0, got {weight!r}")
    return ContactOperators(Z=Z, S=M + 1.0 / weight, weight=float(weight))


def solve_contact_qp(S: np.ndarray, g: np.ndarray, lam0: np.ndarray | None = None,
                     max_iter: int | None = None) -> np.ndarray:
    """Exact solution of ``min 1/2 lam^T S lam + g^T lam  s.t.  lam >= 0`` (S SPD).

    A primal active-set method (Nocedal & Wright, Algorithm 16.3, for bound
    constraints), warm-started from ``lam0 >= 0``: on the free set F it solves
    ``S_FF lam_F = -g_F`` exactly (Cholesky); a negative entry blocks the step
    and joins the bound set; an optimal point of the subproblem whose
    multipliers ``w = S lam + g`` are negative on the bound set frees the most
    negative one. It ends at ``lam >= 0, w >= 0, lam_i w_i = 0`` to rounding.
    Falls back to Lawson-Hanson NNLS if it ever cycles.
    """
    n = g.size
    lam = np.zeros(n) if lam0 is None else np.maximum(np.asarray(lam0, dtype=float), 0.0)
    free = lam > 0.0
    scale = max(np.abs(g).max(initial=0.0), np.abs(np.diag(S)).max(initial=0.0) * np.abs(lam).max(initial=0.0))
    tol = 64.0 * np.finfo(float).eps * max(scale, np.finfo(float).tiny) * max(1.0, np.sqrt(n))
    limit = max_iter if max_iter is not None else 4 * n + 20
    for _ in range(limit):
        F = np.flatnonzero(free)
        y = np.zeros(n)
        if F.size:
            y[F] = sla.cho_solve(sla.cho_factor(S[np.ix_(F, F)]), -g[F])
        if np.all(y[F] >= 0.0):
            lam = y
            w = S @ lam + g
            w[free] = np.inf
            j = int(np.argmin(w))
            if n == 0 or w[j] >= -tol:
                return lam
            free[j] = True
        else:
            blocking = F[y[F] < 0.0]
            ratios = lam[blocking] / (lam[blocking] - y[blocking])
            alpha = ratios.min()
            lam = lam + alpha * (y - lam)
            hit = blocking[ratios <= alpha]
            lam[hit] = 0.0
            free[hit] = False
            lam[~free] = 0.0
    return nnls_fallback(S, g)


#: the dual QP of step (ii): "active-set" (:func:`solve_contact_qp`, exact to rounding) or
#: "osqp" (:class:`OSQPContactQP`)
CONTACT_QP = ("active-set", "osqp")

#: OSQP's eps_abs = eps_rel for the contact QP; its polishing then solves the KKT system
#: on the contact set ADMM found, exact to rounding when that set is right
OSQP_CONTACT_EPS = 1e-9

#: ADMM iterations of one contact QP (warm-started, a few dozen suffice once Uzawa settles)
OSQP_CONTACT_MAX_ITER = 20_000


def osqp_polish_key() -> str:
    """OSQP's name of its polishing setting: ``polishing`` from 1.0 on, ``polish`` before."""
    import osqp

    return "polish" if str(getattr(osqp, "__version__", "1")).startswith("0.") else "polishing"


class OSQPContactQP:
    """The dual QP of step (ii), ``min 1/2 lam^T S lam + g^T lam``, ``lam >= 0``, by OSQP
    (Stellato et al. 2020: ADMM with one factorisation, then solution polishing).

    ``S`` never changes during a run: OSQP is set up (and its KKT matrix factored)
    once, and each call only updates ``q = g`` and warm-starts from ``lam0``. Same
    call as :func:`solve_contact_qp`; ``S`` is checked to be the one it was set up
    with. ``solves`` and ``unpolished`` (answers whose polishing failed, accurate to
    ``eps`` only) are counted for the run's message.
    """

    def __init__(self, S: np.ndarray, eps: float = OSQP_CONTACT_EPS, max_iter: int = OSQP_CONTACT_MAX_ITER):
        import osqp

        n = S.shape[0]
        self.S = S
        self.solver = osqp.OSQP()
        self.solver.setup(sp.triu(sp.csc_matrix(S), format="csc"), np.zeros(n), sp.identity(n, format="csc"),
                          np.zeros(n), np.full(n, np.inf), eps_abs=eps, eps_rel=eps, max_iter=max_iter, warm_starting=True,
                          verbose=False, **{osqp_polish_key(): True})
        self.solves = 0
        self.unpolished = 0

    def __call__(self, S: np.ndarray, g: np.ndarray, lam0: np.ndarray | None = None,
                 max_iter: int | None = None) -> np.ndarray:
        if S is not self.S:
            raise ValueError("OSQPContactQP is set up for one matrix S")
        self.solver.update(q=np.asarray(g, dtype=float))
        if lam0 is not None:
            self.solver.warm_start(x=np.maximum(np.asarray(lam0, dtype=float), 0.0))
        try:
            res = self.solver.solve(raise_error=False)
        except TypeError:  # osqp 0.6: no raise_error
            res = self.solver.solve()
        self.solves += 1
        if int(getattr(res.info, "status_polish", 0)) != 1:
            self.unpolished += 1
        return np.maximum(np.array(res.x, dtype=float), 0.0)


def nnls_fallback(S: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The same QP as NNLS: with ``S = L L^T``, ``min |L^T lam + L^{-1} g|^2``."""
    from scipy.optimize import nnls

    L = np.linalg.cholesky(S)
    return nnls(L.T, -sla.solve_triangular(L, g, lower=True), maxiter=50 * g.size)[0]


def project_contact(
    u: np.ndarray,
    U: float,
    r: np.ndarray,
    rho: float,
    force: float,
    N: sp.spmatrix,
    psi: np.ndarray,
    solve: Solve,
    ops: ContactOperators,
    lam0: np.ndarray | None = None,
    qp=None,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Step (ii): the projection onto K_h in the metric ``G + w`` (``w = ops.weight``).

    ``(u^{n+1}, U^{n+1})`` minimises ``1/2 |v - u|_G^2 + w/2 (V - U)^2 + rho r.v - rho F V``
    over ``N v + psi - V >= 0``, with ``r = sum_T |T| B_T^T sigma_T^{n+1}``. The
    unconstrained minimiser is ``v* = u - rho G^{-1} r``, ``V* = U + rho F / w``;
    with multipliers ``lam >= 0`` the minimiser is ``v = v* + Z lam``,
    ``V = V* - sum(lam) / w``, where lam solves the dual QP
    ``min 1/2 lam^T S lam + lam^T g*``, ``g* = N v* + psi - V*``, ``lam >= 0``
    (:func:`solve_contact_qp`). The new gaps are ``g* + S lam >= 0``.
    At a fixed point ``r = N^T lam / rho``: ``lam / rho`` are the contact forces.
    ``qp(S, g, lam0)`` solves the dual QP (``None``: :func:`solve_contact_qp`; or an
    :class:`OSQPContactQP`). Returns ``(u_new, U_new, lam)``.
    """
    w = ops.weight
    v_star = u - rho * solve(r) if rho else np.array(u, dtype=float)
    V_star = U + rho * force / w
    g_star = N @ v_star + psi - V_star
    lam = (solve_contact_qp if qp is None else qp)(ops.S, g_star, lam0)
    on = np.flatnonzero(lam)
    return v_star + ops.Z[:, on] @ lam[on], float(U + (rho * force - lam.sum()) / w), lam


class DirectProjection:
    """Step (ii) with G factored and ``Z = G^{-1} N^T`` formed
    (:func:`project_contact`): exact, for small problems and as the reference."""

    backend = "direct"

    def __init__(self, solve: Solve, ops: ContactOperators, contact_qp: str = "active-set"):
        self.solve, self.ops = solve, ops
        self.qp = OSQPContactQP(ops.S) if contact_qp == "osqp" else None

    @property
    def weight(self) -> float:
        return self.ops.weight

    def __call__(self, u, U, r, rho, force, N, psi, lam0=None, start=None):
        return project_contact(u, U, r, rho, force, N, psi, self.solve, self.ops, lam0, self.qp)


class IterativeProjection:
    """Step (ii) without ``Z``: the primal projection QP solved by a primal-dual
    active set method whose face systems are solved by AMG-preconditioned CG.

    In the variables ``y = (v with w_i = v_{i,d} - V at the contact dofs, V)``
    the projection is ``min 1/2 d^T H d + g^T d`` over steps ``d`` with
    ``w_i + d_i >= -psi_i``, where ``H = T^T diag(G, weight) T``
    (:class:`~elastoplast.linalg.amg.FaceSystems`) and ``g = T^T (rho r, -rho F)``.
    The active set ``W`` (Hintermueller, Ito & Kunisch's primal-dual active set
    strategy, warm-started from the last projection) fixes ``w_i = -psi_i`` on
    ``W``; the face system gives ``d``; the multipliers are ``mu = (H d + g)_c``.
    It stops when no inactive bound is violated and no multiplier on ``W`` is
    negative: the KKT conditions of the QP, up to the CG residual ``rtol``
    (relative to the right-hand side, which vanishes at Uzawa's fixed point,
    so the error of each step shrinks with the step). ``mu`` are the contact
    multipliers ``lam`` of :func:`project_contact`. Each Uzawa step costs one
    face solve once the contact set has settled.
    """

    backend = "amg"

    def __init__(self, nd: Discretization, length: float, M: np.ndarray, weight: float | None = None,
                 rtol: float = 1e-6, reuse: bool = True):
        from elastoplast.fem.assembly import assemble
        from elastoplast.linalg.amg import FaceSystems, contact_dofs
        from elastoplast.linalg.blocks import block_layout

        lay = block_layout(nd, length)
        self.cdofs = contact_dofs(nd)
        self.faces = FaceSystems(lay, nd.free, self.cdofs, assemble(lay, M), 0.0, reuse, RECYCLE)
        if weight is None:
            weight = 1.0 / (RIGID_WEIGHT_FACTOR * max(self._trace_estimate(nd), np.finfo(float).tiny))
        if not (np.isfinite(weight) and weight > 0):
            raise InputError("rigid_weight", f"must be a number > 0, got {weight!r}")
        self.faces.weight = float(weight)
        self.faces.set_matrix(self.faces.data)
        self.rtol = rtol
        self.active = np.zeros(nd.n_contact, dtype=bool)
        self.cg_iterations = 0
        self.active_set_iterations = 0

    @property
    def weight(self) -> float:
        return self.faces.weight

    def _trace_estimate(self, nd: Discretization) -> float:
        """``trace(N G^{-1} N^T)`` from ``(G^{-1})_ii`` at up to
        :data:`TRACE_SAMPLES` contact nodes spread over their numbering, times
        ``n_contact / samples`` (the automatic weight only needs its order of
        magnitude; the contact-node compliances differ by small factors)."""
        n_c = nd.n_contact
        picks = np.unique(np.linspace(0, n_c - 1, min(n_c, TRACE_SAMPLES)).round().astype(int))
        total = 0.0
        for i in picks:
            e = np.zeros(nd.n_free)
            e[self.cdofs[i]] = 1.0
            total += self.faces.solve_plain(e, TRACE_RTOL)[self.cdofs[i]]
        return total * n_c / picks.size

    def __call__(self, u, U, r, rho, force, N, psi, lam0=None, start=None):
        """The projection of :func:`project_contact` (same arguments and
        results); ``start = (v0, V0)`` in K_h (the last answer, when the
        centre ``u`` is not near it, as in ALG2) is where the search starts:
        the face solves are then for the change from it."""
        faces, cd = self.faces, self.cdofs
        centre = np.append(u, U)
        centre[cd] -= U
        g = np.append(rho * r, rho * (r[cd].sum() - force))
        if start is None:
            y = centre
        else:
            y = np.append(start[0], start[1])
            y[cd] -= start[1]
            g = g + faces.matvec(y - centre)
        lower = -psi
        W = self.active.copy()
        seen = set()
        for _ in range(ACTIVE_SET_MAX_ITER):
            fixed = np.zeros(y.size, dtype=bool)
            fixed[cd[W]] = True
            d_fixed = np.zeros(y.size)
            d_fixed[cd[W]] = lower[W] - y[cd[W]]
            rhs = -g - faces.matvec(d_fixed) if W.any() else -g
            d, info = faces.solve(fixed, rhs, self.rtol)
            d[fixed] = d_fixed[fixed]
            self.cg_iterations += info["cg_iterations"]
            self.active_set_iterations += 1
            mu = faces.matvec_contact(d) + g[cd]
            w_new = y[cd] + d[cd]
            violated = ~W & (w_new < lower)
            negative = W & (mu < 0.0)
            if not (violated.any() or negative.any()):
                break
            seen.add(W.tobytes())
            W = (W & ~negative) | violated
            if W.tobytes() in seen:  # a cycle: keep the last solution
                break
        self.active = W
        y_new = y + d
        y_new[cd] = np.maximum(y_new[cd], lower)  # rounding of the CG solution
        U_new = float(y_new[-1])
        u_new = y_new[:-1]
        u_new[cd] += U_new
        return u_new, U_new, np.where(W, np.maximum(mu, 0.0), 0.0)


#: contact nodes whose ``(G^{-1})_ii`` estimate the trace for the automatic weight of V
TRACE_SAMPLES = 4


#: relative residual of those solves (the weight needs only its order of magnitude). CG's
#: ``(G^{-1})_ii`` estimate ``e_i^T x_k = |x_k|_G^2`` rises monotonically to its limit and is
#: within 0.3% of it at 1e-1. Measured on the default 3D problem (Uzawa and FISTA, AMG path):
#: 1e-2 -> 1e-1 takes 3 CG iterations a solve instead of 5 at 118k and 375k tetrahedra, the
#: trace 300.14 / 516.30 against 300.79 / 517.65, and the same iterations, face solves and
#: CG iterations (uzawa 40 / 47 / 94 at 118k, 50 / 76 / 119 at 375k; uzawa-fast 40 / 52 /
#: 116 and 45 / 67 / 145)
TRACE_RTOL = 1e-1


#: earlier face solutions from which each face solve of step (ii) starts (Galerkin)
RECYCLE = 8


#: active-set iterations of one iterative projection (it stops at a cycle too)
ACTIVE_SET_MAX_ITER = 50


#: "auto": the metric is solved by AMG-preconditioned CG from this many elements on,
#: by dimension. Measured (benchmarks/scale, the 3D sphere, Uzawa to KKT 1e-8, CPU
#: seconds, direct / AMG): 2.7 / 3.4 at 24k tetrahedra, 8.6 / 8.7 at 53k, 27 / 24 at
#: 118k, with 0.50 / 0.27 GB at 53k and 1.46 / 0.48 GB at 118k (Z = G^{-1} N^T is
#: dense). 2D (cylinder_2d): direct 5.8 / AMG 13.4 s at 25.6k triangles, direct
#: 24.4 s at 102k (benchmarks/scale/README.md): "auto" stays direct in 2D.
UZAWA_AMG_FROM_ELEMENTS = {2: 10_000_000, 3: 50_000}


def iterative_metric(disc: Discretization, method: str) -> bool:
    """Whether step (ii) goes the iterative way: ``"amg"``, or ``"auto"`` from
    :data:`UZAWA_AMG_FROM_ELEMENTS` elements on."""
    return method == "amg" or (method == "auto" and disc.n_elements >= UZAWA_AMG_FROM_ELEMENTS[disc.dim])


def iterative_context(disc: Discretization, method: str):
    """One BLAS thread on the iterative path (:func:`~elastoplast.linalg.amg.one_blas_thread`), else nothing."""
    from elastoplast.linalg.amg import one_blas_thread

    return one_blas_thread() if iterative_metric(disc, method) else contextlib.nullcontext()


def metric_projection(nd: Discretization, length: float, M: np.ndarray, method: str = "auto",
                      weight: float | None = None, rtol: float = 1e-6, contact_qp: str = "active-set"):
    """Step (ii) in the metric ``sum_T |T| B_T^T M B_T`` (+ ``weight`` for V):
    :class:`IterativeProjection` when :func:`iterative_metric`, else
    :class:`DirectProjection` with the factorisation ``method`` and the dual QP
    ``contact_qp`` (:data:`CONTACT_QP`; the iterative path has no dual QP, so "osqp"
    is refused there)."""
    if contact_qp not in CONTACT_QP:
        raise InputError("contact_qp", f"must be one of {list(CONTACT_QP)}, got {contact_qp!r}")
    if iterative_metric(nd, method):
        if contact_qp != "active-set":
            raise InputError("contact_qp", f"{contact_qp!r} solves the dual QP of the direct step (ii); with "
                                           f"{nd.n_elements:,} elements and factorization={method!r} step (ii) is "
                                           "iterative (AMG-CG) and has none: choose a factorization such as "
                                           "'superlu'")
        return IterativeProjection(nd, length, M, weight, rtol)
    solve = factorize_spd(nd.weighted_gram(M).tocsc(), method)
    return DirectProjection(solve, contact_operators(nd.N, solve, weight), contact_qp)


def projection_note(proj) -> str:
    """What the answer's message says about step (ii) when it is not the default
    direct one: the iterative path's work, or OSQP's contact QPs."""
    if proj.backend != "amg":
        qp = getattr(proj, "qp", None)
        if qp is None:
            return ""
        return f"; step (ii)'s contact QP by OSQP: {qp.solves} solves, {qp.unpolished} not polished"
    return (f"; step (ii) by AMG-CG: {proj.faces.setups} AMG set-up(s), {proj.active_set_iterations} face solves, "
            f"{proj.cg_iterations} CG iterations")
