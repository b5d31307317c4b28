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
  return mapping (:func:`~elastoplast.fem.material.consistent_tangent`:
  ``C_ep = C - 6 mu^2/(3 mu + H) n n^T - 6 mu^2 dkappa/q (Dev - n n^T)`` on
  plastic elements, from differentiating the radial return); the active variables go to their
  bound, the Hessian row of ``U`` couples the rigid body to every contact node;
* an Armijo line search on f along the projection arc ``P[y + alpha d]``, which
  keeps every iterate feasible and makes the method converge from ``u = 0``.

The Hessian keeps one sparsity pattern for every active set (active rows and
columns are replaced by their diagonal), so the sparse factorisation's
symbolic analysis is done once; with PARDISO a stale factorisation also serves
as a preconditioner for conjugate gradients while that is cheaper than
refactorising (:class:`NewtonOptions`). On large meshes the face systems are
solved inexactly instead, by conjugate gradients with smoothed-aggregation AMG
(:class:`AMGHessian`, :mod:`elastoplast.linalg.amg`), to the relative residual of
Eisenstat and Walker's forcing term (:func:`forcing_term`); every CG iterate
is a descent direction on the face, so the line search and the projection
arc are unchanged. Every iterate is judged by the KKT certificate of
docs/certificate.md, whatever the linear solver.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from elastoplast.fem.discretize import Discretization, nondimensionalize
from elastoplast.solvers.loop import Monitor, Verdict
from elastoplast.linalg.amg import FaceSystems, assemble, block_layout, contact_dofs, one_blas_thread, pcg
from elastoplast.fem.material import consistent_tangent, return_mapping
from elastoplast.problem.options import LOOSEST_TOL, TIGHTEST_TOL, SolverOptions, option
from elastoplast.certificate.kkt import energy_density
from elastoplast.certificate.solution import Solution, Status


@dataclass(frozen=True)
class NewtonOptions(SolverOptions):
    """Settings of :func:`solve_newton` (``tol``, ``max_iter``, ``time_limit``,
    ``progress``: :class:`~elastoplast.problem.options.SolverOptions`).

    ``linear_solver``: ``"pardiso"`` (MKL, via pypardiso), ``"splu"`` (SciPy),
    ``"amg"`` (conjugate gradients with smoothed-aggregation AMG,
    :class:`AMGHessian`) or ``"auto"``: AMG from :data:`AMG_FROM_ELEMENTS`
    elements on, PARDISO below when installed, else SuperLU. Measured on the 3D
    sphere with 111k tetrahedra (52k dofs): PARDISO 0.5 s analysis + 2.1 s
    factorisation, SciPy's SuperLU 41 s (COLAMD), cholespy 53 s (see
    benchmarks/methods/README.md); the direct and iterative paths against each
    other from 12k to 1M tetrahedra in benchmarks/scale.
    ``forcing_max`` (AMG only): the loosest relative residual asked of a Newton
    step's linear solve (:func:`forcing_term` tightens it as Newton converges).
    ``amg_reuse`` (AMG only): keep a multigrid hierarchy across steps while a new
    one would not pay for itself (:class:`~elastoplast.linalg.amg.FaceSystems`).
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
    linear_solver: str = option("auto", str, "linear solver of the Newton systems",
                                choices=("auto", "pardiso", "splu", "amg"))
    reuse_factorization: bool = option(False, bool, "try CG preconditioned by the last factorisation first")
    load_steps: int = option(1, int, "solve for F/n, 2F/n, ..., F in turn", lo=1, hi=1000)
    threads: int | None = option(None, int, "MKL threads for PARDISO (none: MKL's default)", lo=1, hi=1024,
                                 none=True, persist=False)
    armijo: float = option(1e-4, float, "sufficient-decrease constant of the line search", lo=0.0, hi=0.5,
                           lo_open=True)
    forcing_max: float = option(1e-2, float, "amg: largest relative residual of a Newton step's linear solve",
                                lo=1e-12, hi=0.5)
    amg_reuse: bool = option(True, bool, "amg: keep a multigrid hierarchy while a new one would not pay for itself")


#: "auto" takes AMG-preconditioned CG from this many elements on, by the direct
#: solver it would otherwise use and the dimension. Measured (benchmarks/scale, the
#: 3D sphere, Newton to KKT 1e-8, CPU seconds): AMG against PARDISO 0.7 / 1.4 s at
#: 12k tetrahedra, 1.2 / 2.7 at 24k, 3.5 / 8.6 at 53k, 10.5 / 30 at 118k, 36 / 184
#: at 375k; AMG wins from the smallest size measured, so below 20k, where both take
#: about a second, the direct path (exact, the reference) is kept. SuperLU is slower
#: than PARDISO (41 s for one factorisation at 111k). 2D (cylinder_2d, benchmarks/scale
#: README.md): PARDISO 2.2 / AMG 5.1 s at 25.6k triangles, 7.1 / 42.9 s at 102k: direct
#: factorisations fill in little in 2D, so "auto" stays direct there at any size here.
AMG_FROM_ELEMENTS = {"pardiso": {2: 10_000_000, 3: 20_000}, "splu": {2: 10_000_000, 3: 20_000}}


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


def assemble_hessian(lay: HessianLayout, volumes: np.ndarray, elements: np.ndarray, tangents: np.ndarray,
                     elastic: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Upper-triangle CSR values of ``T^T diag(K_t, 0) T`` in the variables y.

    ``K_t = sum_T |T| B_T^T C_ep,T B_T``; with ``u = y_u + U e_c`` (``e_c`` the
    indicator of the vertical contact dofs) the Hessian in y is
    ``[[K_t, K_t e_c], [e_c^T K_t, e_c^T K_t e_c]]``. ``tangents`` are
    ``C_ep`` of ``elements`` (one ``(k, k)`` matrix for all of them, or one each).
    With ``elastic = (C, values of K for C everywhere)`` only ``elements``
    (the plastic ones) are assembled, as a correction ``C_ep - C``.
    """
    if elastic is None:
        C, data = 0.0, np.zeros(lay.indices.size)
    else:
        C, base = elastic
        data = base.copy()
    Bl = lay.B_local[elements]
    DB = np.matmul((tangents - C) * volumes[elements, None, None], Bl)
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


# ----------------------------------------------------------------------------
# the method
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class State:
    """An iterate in the variables y and what the return mapping gives there:
    ``plastic`` the indices of the plastic elements, ``tangent`` their consistent
    tangents ``(n_plastic, k, k)`` (elsewhere the tangent is C), None for a
    trial point of the line search."""

    y: np.ndarray
    u: np.ndarray
    U: float
    sigma: np.ndarray
    xi: np.ndarray
    plastic: np.ndarray
    tangent: np.ndarray | None
    grad: np.ndarray
    energy: float

    def with_tangent(self, disc: Discretization) -> "State":
        """The same iterate with its consistent tangents (computed on the plastic elements only)."""
        if self.tangent is not None:
            return self
        eps = disc.strain(self.u)[self.plastic]
        return replace(self, tangent=consistent_tangent(disc.material, eps)[2])


def to_displacements(y: np.ndarray, cdofs: np.ndarray) -> tuple[np.ndarray, float]:
    """``(u, U)`` from y: ``u_c = w + U`` at the vertical contact dofs."""
    u = y[:-1].copy()
    u[cdofs] += y[-1]
    return u, float(y[-1])


def to_variables(u: np.ndarray, U: float, cdofs: np.ndarray) -> np.ndarray:
    y = np.append(u, U)
    y[cdofs] -= U
    return y


def evaluate(disc: Discretization, cdofs: np.ndarray, y: np.ndarray, tangent: bool = True) -> State:
    """Stresses, gradient ``T^T (r, -F)``, energy f and (if ``tangent``) the
    consistent tangents of the plastic elements at y.

    The gradient is ``r = sum_T |T| B_T^T sigma_T`` on the u part (the contact
    rows give ``lam_i = r_{i,d}``) and ``sum_i lam_i - F`` for U.
    """
    u, U = to_displacements(y, cdofs)
    sigma, xi, dkappa = return_mapping(disc.material, disc.strain(u))
    r = disc.internal_force(sigma)
    grad = np.append(r, r[cdofs].sum() - disc.force)
    st = State(y, u, U, sigma, xi, np.flatnonzero(dkappa > 0.0), None, grad, energy(disc, sigma, xi, dkappa, U))
    return st.with_tangent(disc) if tangent else st


def energy(disc: Discretization, sigma: np.ndarray, xi: np.ndarray, kappa: np.ndarray, U: float) -> float:
    """f = (D)'s objective, :func:`~elastoplast.certificate.solution.value_displacement_form`,
    from the return mapping already done at the point (one mapping per line-search
    trial, not two): ``sum_T |T| (1/2 sigma A sigma + 1/2 xi^2 / H + sigma_y kappa) - F U``
    (``xi = H kappa``, so ``xi^2 / H = H kappa^2``)."""
    density = 0.5 * energy_density(disc, sigma, xi) + disc.material.yield_stress * kappa
    return float(disc.volumes @ density) - disc.force * U


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


class DirectHessian:
    """Newton's matrix on the fixed upper-triangle pattern of :func:`hessian_layout`,
    face systems factored by :class:`SPDSolver` (the reference path).

    With ``reuse_factorization`` the face system is first tried by conjugate
    gradients preconditioned by the last factorisation, to relative residual
    ``min(1e-4, kkt)`` and within the iterations that cost less than a
    refactorisation.
    """

    def __init__(self, nd: Discretization, options: "NewtonOptions", backend: str):
        self.lay = hessian_layout(nd)
        self.linear = SPDSolver(self.lay, backend, options.threads)
        self.backend = self.linear.backend
        self.reuse = options.reuse_factorization
        C = nd.material.stiffness(nd.dim)
        self.elastic = (C, assemble_hessian(self.lay, nd.volumes, np.arange(nd.n_elements), C))
        self.volumes = nd.volumes
        self.costs = {"factored": False}
        self.data = self.elastic[1]

    def update(self, st: State) -> None:
        self.data = assemble_hessian(self.lay, self.volumes, st.plastic, st.tangent, self.elastic)

    def diagonal(self) -> np.ndarray:
        return self.data[self.lay.diag]

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return upper_matvec(self.lay, self.data, x)

    def solve_face(self, fixed: np.ndarray, rhs: np.ndarray, d_fixed: np.ndarray, rtol: float, kkt_worst: float,
                   timings: dict) -> tuple[np.ndarray, dict]:
        """``H_FF x_F = rhs_F``, ``x_A = d_fixed_A`` (exactly; ``rtol`` is for the iterative path)."""
        lay, data = self.lay, self.data
        face = fix_variables(lay, data, fixed)
        rhs = rhs.copy()
        rhs[fixed] = data[lay.diag][fixed] * d_fixed[fixed]
        info = {"factorized": False, "cg_iterations": 0}
        costs = self.costs
        if self.reuse and costs["factored"]:
            t0 = time.perf_counter()
            budget = max(1, int(min(60, 0.3 * costs["factor"] / costs["solve"])))
            x, its, ok = pcg(lambda v: upper_matvec(lay, face, v), self.linear.solve, rhs, None,
                             min(1e-4, max(1e-12, kkt_worst)), budget)
            timings["solve"] += time.perf_counter() - t0
            info["cg_iterations"] = its
            if ok:
                return x, info
        t0 = time.perf_counter()
        self.linear.factor(face)
        t1 = time.perf_counter()
        x = self.linear.solve(rhs)
        t2 = time.perf_counter()
        costs.update(factored=True, factor=t1 - t0, solve=t2 - t1)
        timings["factorization"] += t1 - t0
        timings["solve"] += t2 - t1
        info["factorized"] = True
        return x, info

    def release(self) -> None:
        self.linear.release()


class AMGHessian:
    """Newton's matrix for conjugate gradients with smoothed-aggregation AMG.

    The tangent stiffness ``K_t`` is kept as BSR over every dof
    (:mod:`elastoplast.linalg.amg`): the elastic one assembled once, the plastic
    elements' ``C_ep - C`` added at each step. The face systems, with U
    eliminated inside the preconditioner and the multigrid hierarchy kept while
    that pays, are :class:`~elastoplast.linalg.amg.FaceSystems`; each is solved to
    the relative residual the forcing term asks for.
    """

    backend = "amg"

    def __init__(self, nd: Discretization, units, options: "NewtonOptions", cdofs: np.ndarray):
        self.lay = block_layout(nd, units.length)
        self.C = nd.material.stiffness(nd.dim)
        self.elastic = assemble(self.lay, self.C)
        self.faces = FaceSystems(self.lay, nd.free, cdofs, self.elastic, reuse=options.amg_reuse)

    @property
    def setups(self) -> int:
        return self.faces.setups

    def update(self, st: State) -> None:
        data = self.elastic.copy()
        if st.plastic.size:
            assemble(self.lay, st.tangent, st.plastic, out=data, subtract=self.C)
        self.faces.set_matrix(data)

    def diagonal(self) -> np.ndarray:
        return self.faces.diagonal()

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return self.faces.matvec(x)

    def solve_face(self, fixed: np.ndarray, rhs: np.ndarray, d_fixed: np.ndarray, rtol: float, kkt_worst: float,
                   timings: dict) -> tuple[np.ndarray, dict]:
        x, info = self.faces.solve(fixed, rhs, rtol, max_iter=CG_MAX_ITER)
        timings["factorization"] += info.pop("setup_time")
        timings["solve"] += info.pop("solve_time")
        x[fixed] = d_fixed[fixed]
        return x, info

    def release(self) -> None:
        self.faces.release()


#: conjugate-gradient iteration limit of one Newton step (the direction is a
#: descent direction at every CG iterate, so a step cut short is still usable)
CG_MAX_ITER = 1000


def forcing_term(kkt: float, kkt_prev: float | None, eta_prev: float | None, eta_max: float, tol: float) -> float:
    """Relative residual asked of the linear solve (inexact Newton).

    Eisenstat & Walker's choice 2 (1996), ``eta = 0.9 (kkt / kkt_prev)^2``,
    with their safeguard ``eta >= 0.9 eta_prev^2`` when that exceeds 0.1,
    capped by ``eta_max``; ``kkt`` is the certificate's worst residual, so the
    solve tightens as the iteration converges superlinearly. It is never
    tighter than ``0.1 tol / kkt``: a step whose linear error is that small
    already lands below ``tol`` (no oversolving), nor than 1e-12.
    """
    if kkt_prev is None or eta_prev is None or not (kkt_prev > 0 and np.isfinite(kkt)):
        return eta_max
    eta = 0.9 * (kkt / kkt_prev) ** 2
    if 0.9 * eta_prev**2 > 0.1:
        eta = max(eta, 0.9 * eta_prev**2)
    return float(min(eta_max, max(eta, 0.1 * tol / kkt, 1e-12)))


def newton_direction(hess, st, cdofs, lower, rtol, kkt_worst, timings):
    """Newton step on the face of the eps-active set: the active contact
    variables go to their bound, the others solve ``H_FF d_F = -grad_F - H_FA d_A``
    (to relative residual ``rtol`` on the iterative path)."""
    t0 = time.perf_counter()
    hess.update(st)
    timings["assembly"] += time.perf_counter() - t0
    act = active_set(st, cdofs, lower, hess.diagonal())
    n = st.y.size
    fixed = np.zeros(n, dtype=bool)
    fixed[cdofs[act]] = True
    d_fixed = np.zeros(n)
    d_fixed[cdofs[act]] = lower[act] - st.y[cdofs[act]]
    rhs = -st.grad - hess.matvec(d_fixed)
    return hess.solve_face(fixed, rhs, d_fixed, rtol, kkt_worst, timings)


def line_search(disc, cdofs, lower, st, direction, armijo):
    """Armijo backtracking along the projection arc ``P[y + alpha d]``:
    accept when ``f(y_alpha) <= f(y) + armijo grad . (y_alpha - y)`` (up to
    rounding of f). Returns ``(state or None, alpha)``."""
    alpha = 1.0
    for _ in range(40):
        trial = project(st.y + alpha * direction, cdofs, lower)
        cand = evaluate(disc, cdofs, trial, tangent=False)
        if cand.energy <= st.energy + armijo * (st.grad @ (trial - st.y)) + 1e-14 * abs(st.energy):
            return cand.with_tangent(disc), alpha
        alpha *= 0.5
    return None, alpha


def choose_backend(disc: Discretization, requested: str) -> str:
    """The linear solver for ``requested``: ``"auto"`` takes AMG from
    :data:`AMG_FROM_ELEMENTS` elements on (the measured crossover with the
    direct solver available), PARDISO below it when installed, else SuperLU."""
    if requested in ("amg", "pardiso", "splu"):
        return requested
    direct = "pardiso" if pardiso_available() else "splu"
    return "amg" if disc.n_elements >= AMG_FROM_ELEMENTS[direct][disc.dim] else direct


@functools.cache
def pardiso_available() -> bool:
    try:
        SPDSolver._pardiso(None)
    except Exception:  # not installed, or its internals moved
        return False
    return True


def _newton_loop(nd, monitor, hess, cdofs, lower, y, options, timings, backend):
    """Newton steps over the load steps until the monitor stops; returns ``(verdict, state, steps)``."""
    steps = options.load_steps
    iteration, info = 0, {}
    kkt_prev, eta = None, None
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
                kkt = monitor.last.worst
                eta = forcing_term(kkt, kkt_prev, eta, options.forcing_max, tol)
                kkt_prev = kkt
                try:
                    direction, info = newton_direction(hess, st, cdofs, lower, eta, kkt, timings)
                except np.linalg.LinAlgError as exc:
                    verdict = Verdict(Status.FAILED, f"Newton: {exc}")
                    break
                if backend == "amg":
                    info["forcing"] = eta
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
        hess.release()
    return verdict, st, iteration


def solve_newton(disc: Discretization, options: NewtonOptions = NewtonOptions(), warm_start: Solution | None = None) -> Solution:
    """Projected semismooth Newton on (D); see the module docstring.

    Works on the nondimensionalised problem; every iterate is judged by
    :class:`~elastoplast.solvers.loop.Monitor` (the certificate), intermediate load
    steps to ``max(tol, 1e-4)``. On the iterative path the linear solves are
    inexact, to the relative residual of :func:`forcing_term`; the stopping
    test is the certificate all the same.
    """
    t_start = time.perf_counter()
    timings = {"setup": 0.0, "assembly": 0.0, "factorization": 0.0, "solve": 0.0, "line_search": 0.0, "certificate": 0.0}
    nd, units = nondimensionalize(disc)
    monitor = Monitor("newton", disc, nd, units, options, t_start=t_start)
    cdofs = contact_dofs(nd)
    backend = choose_backend(nd, options.linear_solver)
    lower = -nd.psi
    if warm_start is not None:
        y = to_variables(disc.free_displacement(warm_start.u) / units.displacement, warm_start.U / units.displacement, cdofs)
        y = project(y, cdofs, lower)
    else:  # u = 0, U = 0, projected: feasible also where the obstacle starts above the plane (psi < 0)
        y = project(np.zeros(nd.n_free + 1), cdofs, lower)
    with one_blas_thread() if backend == "amg" else contextlib.nullcontext():
        hess = AMGHessian(nd, units, options, cdofs) if backend == "amg" else DirectHessian(nd, options, backend)
        timings["setup"] = time.perf_counter() - t_start
        verdict, st, iteration = _newton_loop(nd, monitor, hess, cdofs, lower, y, options, timings, backend)
    note = f"projected semismooth Newton, {hess.backend}"
    if backend == "amg":
        note += f", {hess.setups} AMG set-up(s)"
    return monitor.solution(verdict, st.sigma, st.xi, st.u, st.U, iterations=iteration, timings=timings, note=note)
