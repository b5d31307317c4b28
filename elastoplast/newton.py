"""Semismooth Newton / primal-dual active set on the displacement form (D).

For fixed strains the minimum of (D) over the plastic strains is reached by the
return mapping, so (D) is the convex, once differentiable problem

    minimise  f(u, U) = sum_T |T| W(B_T u) - F U   subject to  N u + psi - U >= 0,

with ``grad W = R`` (the stresses of the return mapping) and a semismooth
gradient. In the variables ``y = (u with the vertical contact dofs replaced by
w_i = u_{i,d} - U, U)`` the contact inequalities become bounds
``w_i >= -psi_i`` (the gap is ``g_i = w_i + psi_i``), and the method is
Bertsekas' projected Newton method for bound constraints:

* the active set: contact variables at (or within ``eps_k`` of) their bound
  whose gradient ``lam_i = r_{i,d}`` pushes into the obstacle;
* the Newton step on the face they define, with the consistent tangent of the
  return mapping (:func:`~elastoplast.material.consistent_tangent`:
  ``C_ep = C - 6 mu^2/(3 mu + H) n n^T - 6 mu^2 dkappa/q (Dev - n n^T)`` on
  plastic elements, from differentiating the radial return); the active variables go to their
  bound, the Hessian row of ``U`` couples the rigid body to every contact node;
* an Armijo line search on f along the projection arc ``P[y + alpha d]``, which
  keeps every iterate feasible and makes the method converge from ``u = 0``.

The Hessian keeps one sparsity pattern for every active set (active rows and
columns are replaced by their diagonal), so the sparse factorisation's
symbolic analysis is done once; with PARDISO a stale factorisation also serves
as a preconditioner for conjugate gradients while that is cheaper than
refactorising (:class:`NewtonOptions`). Every iterate is judged by the KKT
certificate of docs/certificate.md.
"""

from __future__ import annotations

import ctypes
import functools
import os
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .discretize import Discretization, nondimensionalize
from .iteration import Monitor, Verdict
from .material import consistent_tangent
from .options import LOOSEST_TOL, TIGHTEST_TOL, SolverOptions, option
from .solution import Solution, Status, value_displacement_form


@dataclass(frozen=True)
class NewtonOptions(SolverOptions):
    """Settings of :func:`solve_newton` (``tol``, ``max_iter``, ``time_limit``,
    ``progress``: :class:`~elastoplast.options.SolverOptions`).

    ``linear_solver``: ``"pardiso"`` (MKL, via pypardiso), ``"splu"`` (SciPy) or
    ``"auto"`` (PARDISO when installed). Measured on the 3D sphere with 111k
    tetrahedra (52k dofs): PARDISO 0.5 s analysis + 2.1 s factorisation, SciPy's
    SuperLU 41 s (COLAMD), cholespy 53 s (see benchmarks/methods/README.md).
    ``reuse_factorization``: first try conjugate gradients preconditioned by the
    last factorisation (within 0.3 of a factorisation's measured cost). Off by
    default: on the 3D sphere (41k tetrahedra) it saved one factorisation of
    eight and no time, and with a looser CG tolerance (1e-2) the inexact steps
    made the contact set oscillate (28 Newton steps instead of 8).
    ``load_steps``: solve for ``F/n, 2F/n, ..., F`` in turn, each from the last.
    ``threads``: MKL threads for PARDISO (None: MKL's default). On a machine
    shared with other jobs one thread avoids OpenMP's busy waiting.
    """

    tol: float = option(1e-10, float, "bound on every relative KKT residual of the answer",
                        lo=TIGHTEST_TOL, hi=LOOSEST_TOL)
    max_iter: int = option(100, int, "Newton step limit", lo=1, hi=10_000)
    linear_solver: str = option("auto", str, "sparse factorisation of the Newton matrix",
                                choices=("auto", "pardiso", "splu"))
    reuse_factorization: bool = option(False, bool, "try CG preconditioned by the last factorisation first")
    load_steps: int = option(1, int, "solve for F/n, 2F/n, ..., F in turn", lo=1, hi=1000)
    threads: int | None = option(None, int, "MKL threads for PARDISO (none: MKL's default)", lo=1, hi=1024,
                                 none=True, persist=False)
    armijo: float = option(1e-4, float, "sufficient-decrease constant of the line search", lo=0.0, hi=0.5,
                           lo_open=True)


# ----------------------------------------------------------------------------
# the Hessian on a fixed sparsity pattern
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class HessianLayout:
    """Element-by-element assembly of the Hessian of f in the variables y.

    ``B_local (n_el, k, m)`` are the element strain matrices on the ``m``
    local dofs ``local (n_el, m)`` (free-dof numbers, -1 where fixed). The
    upper triangle of the ``(n_free + 1)`` Hessian is stored in CSR with
    ``indptr``/``indices``; ``slots (n_el, m(m+1)/2)`` sends each upper entry
    ``upper`` of an element matrix to its slot (-1: a fixed dof), ``u_slots``/``u_rows`` are the slots of the column
    of U, ``diag`` the diagonal slots, ``row``/``col`` each slot's indices.
    """

    B_local: np.ndarray
    local: np.ndarray
    upper: np.ndarray
    slots: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    row: np.ndarray
    col: np.ndarray
    diag: np.ndarray
    u_slots: np.ndarray
    u_rows: np.ndarray
    contact_dofs: np.ndarray

    @property
    def size(self) -> int:
        return self.indptr.size - 1


def contact_dofs(disc: Discretization) -> np.ndarray:
    """Free-dof number of the vertical dof of each contact node (rows of N)."""
    N = disc.N.tocsr()
    return N.indices[N.indptr[:-1]]


def hessian_layout(disc: Discretization) -> HessianLayout:
    """Local strain matrices and the fixed pattern of the Hessian (done once)."""
    n_el, k, d = disc.n_elements, disc.k, disc.dim
    m = (d + 1) * d
    position = -np.ones(disc.mesh.n_nodes * d, dtype=np.int64)
    position[disc.free] = np.arange(disc.n_free)
    local = position[(disc.mesh.cells[:, :, None] * d + np.arange(d)).reshape(n_el, m)]
    B = disc.B.tocoo()
    el, comp = B.row // k, B.row % k
    slot = np.argmax(local[el] == B.col[:, None], axis=1)
    B_local = np.zeros((n_el, k, m))
    B_local[el, comp, slot] = B.data  # (row, col) pairs of B are unique

    iu, ju = np.triu_indices(m)
    gi, gj = local[:, iu], local[:, ju]
    keep = ((gi >= 0) & (gj >= 0)).ravel()
    lo, hi = np.minimum(gi, gj).ravel()[keep], np.maximum(gi, gj).ravel()[keep]
    n = disc.n_free + 1
    cdofs = contact_dofs(disc)
    # the column of U: every dof coupled to a contact dof, and U itself
    is_c = np.zeros(n - 1, dtype=bool)
    is_c[cdofs] = True
    touch = is_c[lo] | is_c[hi]
    u_rows = np.unique(np.concatenate([lo[touch], hi[touch]]))
    rows = np.concatenate([lo, u_rows, [n - 1]])
    cols = np.concatenate([hi, np.full(u_rows.size, n - 1), [n - 1]])
    pattern = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))  # sums duplicates, sorts
    pattern.sort_indices()
    indptr, col = pattern.indptr, pattern.indices
    row = np.repeat(np.arange(n), np.diff(indptr))
    uniq = row.astype(np.int64) * n + col
    inverse = np.searchsorted(uniq, rows.astype(np.int64) * n + cols)
    n_el_keys = lo.size
    diag = np.searchsorted(uniq, np.arange(n, dtype=np.int64) * (n + 1))
    slots = -np.ones(keep.size, dtype=np.int64)
    slots[keep] = inverse[:n_el_keys]
    slots = slots.reshape(n_el, iu.size)
    return HessianLayout(
        B_local=B_local, local=local, upper=np.stack([iu, ju]), slots=slots,
        indptr=indptr.astype(np.int64), indices=col.astype(np.int64), row=row, col=col, diag=diag,
        u_slots=inverse[n_el_keys:], u_rows=np.append(u_rows, n - 1), contact_dofs=cdofs,
    )


def assemble_hessian(lay: HessianLayout, volumes: np.ndarray, tangent: np.ndarray,
                     elastic: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Upper-triangle CSR values of ``T^T diag(K_t, 0) T`` in the variables y.

    ``K_t = sum_T |T| B_T^T C_ep,T B_T``; with ``u = y_u + U e_c`` (``e_c`` the
    indicator of the vertical contact dofs) the Hessian in y is
    ``[[K_t, K_t e_c], [e_c^T K_t, e_c^T K_t e_c]]``. With ``elastic = (C,
    values of K for C everywhere)`` only the elements whose tangent differs
    from C (the plastic ones) are assembled, as a correction.
    """
    if elastic is None:
        elements, C, data = np.arange(volumes.size), 0.0, np.zeros(lay.indices.size)
    else:
        C, base = elastic
        elements = np.flatnonzero(np.any(tangent != C, axis=(1, 2)))
        data = base.copy()
    Bl = lay.B_local[elements]
    DB = np.matmul((tangent[elements] - C) * volumes[elements, None, None], Bl)
    Ke = np.matmul(np.swapaxes(Bl, 1, 2), DB)[:, lay.upper[0], lay.upper[1]]
    slots = lay.slots[elements]
    keep = slots >= 0
    data += np.bincount(slots[keep], weights=Ke[keep], minlength=data.size)
    n = lay.size
    K = sp.csr_matrix((data, lay.indices, lay.indptr), shape=(n, n))
    ec = np.zeros(n)
    ec[lay.contact_dofs] = 1.0
    Kec = K @ ec + K.T @ ec - data[lay.diag] * ec  # the full symmetric K times e_c
    data[lay.u_slots[:-1]] = Kec[lay.u_rows[:-1]]
    data[lay.diag[-1]] = ec @ Kec
    return data


def upper_matvec(lay: HessianLayout, data: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``H x`` for the symmetric matrix stored by its upper triangle."""
    n = lay.size
    H = sp.csr_matrix((data, lay.indices, lay.indptr), shape=(n, n))
    return H @ x + H.T @ x - data[lay.diag] * x


def fix_variables(lay: HessianLayout, data: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """The face system: rows and columns of ``fixed`` variables replaced by their diagonal."""
    out = data.copy()
    out[fixed[lay.row] | fixed[lay.col]] = 0.0
    out[lay.diag[fixed]] = data[lay.diag[fixed]]
    return out


# ----------------------------------------------------------------------------
# sparse SPD solves
# ----------------------------------------------------------------------------


@functools.cache
def _mkl_runtime() -> str:
    """Path of MKL's runtime as found by pypardiso at import (its search of
    ``sys.prefix`` takes seconds; new solver objects reuse the result)."""
    import pypardiso

    return pypardiso.ps.libmkl._name


class SPDSolver:
    """Factorisation of symmetric positive definite matrices of one pattern.

    PARDISO (``mtype = 2``, upper triangle) does its symbolic analysis once
    and only refactorises numerically afterwards; SuperLU is the fallback.
    """

    def __init__(self, lay: HessianLayout, backend: str = "auto", threads: int | None = None):
        if backend not in ("auto", "pardiso", "splu"):
            raise ValueError(f"unknown linear solver {backend!r} (auto, pardiso, splu)")
        self.lay = lay
        self.analysed = False
        self.matrix: sp.csr_matrix | None = None
        self.lu = None
        self.backend = "splu"
        if backend != "splu":
            try:
                self.pardiso = self._pardiso(threads)
                self.backend = "pardiso"
            except Exception:  # not installed, or its internals moved (we use private ones)
                if backend == "pardiso":
                    raise

    @staticmethod
    def _pardiso(threads: int | None):
        import pypardiso

        os.environ.setdefault("PYPARDISO_MKL_RT", _mkl_runtime())
        solver = pypardiso.PyPardisoSolver(mtype=2)
        for name in ("set_iparm", "set_phase", "_call_pardiso", "free_memory"):
            getattr(solver, name)  # fail here, not mid-solve, if pypardiso changed
        if threads is not None:
            solver.libmkl.MKL_Set_Num_Threads(ctypes.c_int(int(threads)))
        return solver

    def factor(self, data: np.ndarray) -> None:
        n = self.lay.size
        A = sp.csr_matrix((data, self.lay.indices, self.lay.indptr), shape=(n, n))
        if self.backend == "pardiso":
            self.pardiso.set_iparm(12, 0)
            self.pardiso.set_phase(22 if self.analysed else 12)
            try:
                self.pardiso._call_pardiso(A, np.zeros(n))
            except Exception as exc:  # pypardiso's error type: a non-positive pivot, out of memory
                raise np.linalg.LinAlgError(f"PARDISO could not factor the Newton matrix: {exc}") from exc
            self.analysed = True
            self.matrix = A
        else:
            full = (A + A.T - sp.diags(data[self.lay.diag])).tocsc()
            try:
                self.lu = sla.splu(full)  # COLAMD: 41 s at 111k tetrahedra, MMD_AT_PLUS_A > 9 min
            except RuntimeError as exc:
                raise np.linalg.LinAlgError(f"SuperLU could not factor the Newton matrix: {exc}") from exc

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.backend == "pardiso":
            self.pardiso.set_phase(33)
            return self.pardiso._call_pardiso(self.matrix, np.asfortranarray(b))
        return self.lu.solve(b)

    def release(self) -> None:
        """Free PARDISO's internal memory."""
        if self.backend == "pardiso" and self.analysed:
            self.pardiso.free_memory(everything=True)
        self.lu = None


def preconditioned_cg(matvec, precond, b: np.ndarray, x0: np.ndarray, rtol: float, max_iter: int):
    """Conjugate gradients on ``A x = b`` from ``x0``; returns ``(x, iterations, converged)``."""
    x = x0.copy()
    r = b - matvec(x)
    stop = rtol * np.linalg.norm(b)
    if np.linalg.norm(r) <= stop:
        return x, 0, True
    z = precond(r)
    p = z.copy()
    rz = r @ z
    for it in range(1, max_iter + 1):
        Ap = matvec(p)
        alpha = rz / (p @ Ap)
        x += alpha * p
        r -= alpha * Ap
        if np.linalg.norm(r) <= stop:
            return x, it, True
        z = precond(r)
        rz_new = r @ z
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, max_iter, False


# ----------------------------------------------------------------------------
# the method
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class State:
    """An iterate in the variables y and what the return mapping gives there."""

    y: np.ndarray
    u: np.ndarray
    U: float
    sigma: np.ndarray
    xi: np.ndarray
    plastic: np.ndarray
    tangent: np.ndarray
    grad: np.ndarray
    energy: float


def to_displacements(y: np.ndarray, cdofs: np.ndarray) -> tuple[np.ndarray, float]:
    """``(u, U)`` from y: ``u_c = w + U`` at the vertical contact dofs."""
    u = y[:-1].copy()
    u[cdofs] += y[-1]
    return u, float(y[-1])


def to_variables(u: np.ndarray, U: float, cdofs: np.ndarray) -> np.ndarray:
    y = np.append(u, U)
    y[cdofs] -= U
    return y


def evaluate(disc: Discretization, cdofs: np.ndarray, y: np.ndarray) -> State:
    """Stresses, tangent, gradient ``T^T (r, -F)`` and energy f at y.

    The gradient is ``r = sum_T |T| B_T^T sigma_T`` on the u part (the contact
    rows give ``lam_i = r_{i,d}``) and ``sum_i lam_i - F`` for U.
    """
    u, U = to_displacements(y, cdofs)
    sigma, xi, tangent = consistent_tangent(disc.material, disc.strain(u))
    plastic = np.any(tangent != disc.material.stiffness(disc.dim), axis=(1, 2))
    r = disc.internal_force(sigma)
    grad = np.append(r, r[cdofs].sum() - disc.force)
    return State(y, u, U, sigma, xi, plastic, tangent, grad, value_displacement_form(disc, u, U))


def project(y: np.ndarray, cdofs: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """Projection onto the bounds ``w_i >= -psi_i``: the feasible set K_h in y."""
    out = y.copy()
    out[cdofs] = np.maximum(out[cdofs], lower)
    return out


def active_set(st: State, cdofs: np.ndarray, lower: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """Bertsekas' eps-active set: contact variables within ``eps_k`` of their
    bound whose gradient (the contact force) is nonnegative, with
    ``eps_k = min(1e-3, |y - P[y - D grad]|_inf)``, ``D`` the inverse Hessian diagonal.

    If it is empty the contact variable nearest its bound is taken, so that the
    face Hessian is nonsingular (U alone is not bounded below)."""
    y, g = st.y, st.grad
    step = y - project(y - g / diag, cdofs, lower)
    eps_k = min(1e-3, float(np.abs(step).max()))
    dist = y[cdofs] - lower
    act = (dist <= eps_k) & (g[cdofs] >= 0.0)
    if not np.any(act):
        act[np.argmin(dist)] = True
    return act


def newton_direction(lay, linear, st, cdofs, lower, volumes, elastic, kkt_worst, options, costs, timings):
    """Newton step on the face of the eps-active set: the active contact
    variables go to their bound, the others solve ``H_FF d_F = -grad_F - H_FA d_A``.

    With ``reuse_factorization`` the system is first tried by conjugate
    gradients preconditioned by the last factorisation, to relative residual
    ``min(1e-2, kkt)`` (a forcing term that keeps the convergence superlinear)
    and within the iterations that cost less than a refactorisation.
    """
    t0 = time.perf_counter()
    data = assemble_hessian(lay, volumes, st.tangent, elastic)
    timings["assembly"] += time.perf_counter() - t0
    act = active_set(st, cdofs, lower, data[lay.diag])
    fixed = np.zeros(lay.size, dtype=bool)
    fixed[cdofs[act]] = True
    d_fixed = np.zeros(lay.size)
    d_fixed[cdofs[act]] = lower[act] - st.y[cdofs[act]]
    face = fix_variables(lay, data, fixed)
    rhs = -st.grad - upper_matvec(lay, data, d_fixed)
    rhs[fixed] = data[lay.diag][fixed] * d_fixed[fixed]
    info = {"factorized": False, "cg_iterations": 0}
    if options.reuse_factorization and costs["factored"]:
        t0 = time.perf_counter()
        budget = max(1, int(min(60, 0.3 * costs["factor"] / costs["solve"])))
        x, its, ok = preconditioned_cg(lambda v: upper_matvec(lay, face, v), linear.solve, rhs,
                                       np.zeros_like(rhs), min(1e-4, max(1e-12, kkt_worst)), budget)
        timings["solve"] += time.perf_counter() - t0
        info["cg_iterations"] = its
        if ok:
            return x, info
    t0 = time.perf_counter()
    linear.factor(face)
    t1 = time.perf_counter()
    x = linear.solve(rhs)
    t2 = time.perf_counter()
    costs.update(factored=True, factor=t1 - t0, solve=t2 - t1)
    timings["factorization"] += t1 - t0
    timings["solve"] += t2 - t1
    info["factorized"] = True
    return x, info


def line_search(disc, cdofs, lower, st, direction, armijo):
    """Armijo backtracking along the projection arc ``P[y + alpha d]``:
    accept when ``f(y_alpha) <= f(y) + armijo grad . (y_alpha - y)`` (up to
    rounding of f). Returns ``(state or None, alpha)``."""
    alpha = 1.0
    for _ in range(40):
        trial = project(st.y + alpha * direction, cdofs, lower)
        cand = evaluate(disc, cdofs, trial)
        if cand.energy <= st.energy + armijo * (st.grad @ (trial - st.y)) + 1e-14 * abs(st.energy):
            return cand, alpha
        alpha *= 0.5
    return None, alpha


def solve_newton(disc: Discretization, options: NewtonOptions = NewtonOptions(), warm_start: Solution | None = None) -> Solution:
    """Projected semismooth Newton on (D); see the module docstring.

    Works on the nondimensionalised problem; every iterate is judged by
    :class:`~elastoplast.iteration.Monitor` (the certificate), intermediate load
    steps to ``max(tol, 1e-4)``.
    """
    t_start = time.perf_counter()
    timings = {"setup": 0.0, "assembly": 0.0, "factorization": 0.0, "solve": 0.0, "line_search": 0.0, "certificate": 0.0}
    nd, units = nondimensionalize(disc)
    monitor = Monitor("newton", disc, nd, units, options, t_start=t_start)
    lay = hessian_layout(nd)
    linear = SPDSolver(lay, options.linear_solver, options.threads)
    cdofs = lay.contact_dofs
    lower = -nd.psi
    C = nd.material.stiffness(nd.dim)
    elastic = (C, assemble_hessian(lay, nd.volumes, np.broadcast_to(C, (nd.n_elements,) + C.shape)))
    timings["setup"] = time.perf_counter() - t_start

    if warm_start is not None:
        y = to_variables(disc.free_displacement(warm_start.u) / units.displacement, warm_start.U / units.displacement, cdofs)
        y = project(y, cdofs, lower)
    else:
        y = np.zeros(nd.n_free + 1)
    steps = options.load_steps
    iteration, info = 0, {}
    costs = {"factored": False}
    try:
        for step in range(1, steps + 1):
            target = nd.with_force(nd.force * step / steps)
            tol = options.tol if step == steps else max(options.tol, 1e-4)
            st = evaluate(target, cdofs, y)
            while True:
                t0 = time.perf_counter()
                verdict = monitor.check(iteration, st.sigma, st.xi, st.u, st.U, tol=tol, nd=target, load_step=step,
                                        energy=st.energy, **info)
                timings["certificate"] += time.perf_counter() - t0
                if verdict is not None:
                    break
                iteration += 1
                try:
                    direction, info = newton_direction(lay, linear, st, cdofs, lower, target.volumes, elastic,
                                                       monitor.last.worst, options, costs, timings)
                except np.linalg.LinAlgError as exc:
                    verdict = Verdict(Status.FAILED, f"Newton: {exc}")
                    break
                t0 = time.perf_counter()
                accepted, alpha = line_search(target, cdofs, lower, st, direction, options.armijo)
                timings["line_search"] += time.perf_counter() - t0
                info["step"] = alpha
                if accepted is None:
                    verdict = Verdict(Status.FAILED, "Newton: line search failed (no decrease of the energy along "
                                                     "the direction)")
                    break
                st = accepted
            if verdict.status is not Status.CONVERGED:
                break
            y = st.y
    finally:
        linear.release()
    return monitor.solution(verdict, st.sigma, st.xi, st.u, st.U, iterations=iteration, timings=timings,
                            note=f"projected semismooth Newton, {linear.backend}")
