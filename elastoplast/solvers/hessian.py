"""Newton's Hessian on a fixed sparsity pattern, and its two solvers: a direct factorisation refactored
numerically at every step, or AMG-preconditioned CG on the node-block matrix."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.assembly import Layout, ScalarView, assemble, scalar_view
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import consistent_tangent
from elastoplast.linalg.amg import FaceSystems, contact_dofs, pcg
from elastoplast.linalg.blocks import block_layout
from elastoplast.linalg.direct import SPDSolver


@dataclass(frozen=True)
class HessianLayout:
    """The fixed pattern of the Hessian of f in the variables y.

    ``view`` is the upper triangle of ``K`` on the free dofs
    (:func:`~elastoplast.fem.assembly.scalar_view` of the discretisation's
    ``layout``) bordered by one more row and column for U, so element
    matrices fill it directly; ``indptr``/``indices`` are its CSR arrays,
    ``u_slots``/``u_rows`` the slots of the column of U and their rows,
    ``diag`` the diagonal slots, ``row``/``col`` each slot's indices.
    """

    layout: Layout
    view: ScalarView
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
        return self.view.n


def bordered(view: ScalarView, rows: np.ndarray) -> tuple[ScalarView, np.ndarray]:
    """``view`` with one more row and column, last, holding ``rows`` (sorted)
    and the new diagonal; returns it and the slots of that column."""
    n = view.n
    extra = np.zeros(n + 1, dtype=np.int64)
    extra[rows] = 1
    extra[n] = 1
    counts = np.append(np.diff(view.indptr), 0) + extra
    indptr = np.zeros(n + 2, dtype=view.indptr.dtype)
    np.cumsum(counts, out=indptr[1:])
    # an old entry moves by the number of new entries in the rows above it
    moved = np.arange(view.size) + np.repeat(indptr[:-2] - view.indptr[:-1], np.diff(view.indptr))
    indices = np.full(indptr[-1], n, dtype=view.indices.dtype)
    indices[moved] = view.indices
    u_slots = indptr[1:][extra > 0] - 1
    slots = np.append(moved, indptr[-1])[view.slots]
    # filled through its slots only: the column of U is no block value, so no ``take``
    return ScalarView(n=n + 1, indptr=indptr, indices=indices, slots=slots, entries=view.entries), u_slots


def hessian_layout(disc: Discretization) -> HessianLayout:
    """The fixed pattern of the Hessian (done once)."""
    view = scalar_view(disc.layout, disc.free, upper=True, slots=True)
    cdofs = contact_dofs(disc)
    # the column of U: every dof coupled to a contact dof, and U itself
    is_c = np.zeros(view.n, dtype=bool)
    is_c[cdofs] = True
    row = np.repeat(np.arange(view.n), np.diff(view.indptr))
    touch = is_c[row] | is_c[view.indices]
    u_rows = np.unique(np.concatenate([row[touch], view.indices[touch]]))
    view, u_slots = bordered(view, u_rows)
    row = np.repeat(np.arange(view.n), np.diff(view.indptr))
    diag = np.flatnonzero(row == view.indices)
    return HessianLayout(layout=disc.layout, view=view, indptr=view.indptr, indices=view.indices, row=row,
                         col=view.indices, diag=diag, u_slots=u_slots, u_rows=np.append(u_rows, view.n - 1),
                         contact_dofs=cdofs)


def assemble_hessian(lay: HessianLayout, elements: np.ndarray | None, tangents: np.ndarray,
                     elastic: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Upper-triangle CSR values of ``T^T diag(K_t, 0) T`` in the variables y.

    ``K_t = sum_T |T| B_T^T C_ep,T B_T``; with ``u = y_u + U e_c`` (``e_c`` the
    indicator of the vertical contact dofs) the Hessian in y is
    ``[[K_t, K_t e_c], [e_c^T K_t, e_c^T K_t e_c]]``. ``tangents`` are
    ``C_ep`` of ``elements`` (one ``(k, k)`` matrix for all of them, or one each;
    None: every element). With ``elastic = (C, values of K for C everywhere)`` only ``elements``
    (the plastic ones) are assembled, as a correction ``C_ep - C``.
    """
    if elastic is None:
        C, data = None, np.zeros(lay.view.size)
    else:
        C, base = elastic
        data = base.copy()
    assemble(lay.layout, tangents, elements, out=data, subtract=C, view=lay.view)
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


class DirectHessian:
    """Newton's matrix on the fixed upper-triangle pattern of :func:`hessian_layout`,
    face systems factored by :class:`SPDSolver` (the reference path).

    With ``reuse_factorization`` the face system is first tried by conjugate
    gradients preconditioned by the last factorisation, to relative residual
    ``min(1e-4, kkt)`` and within the iterations that cost less than a
    refactorisation.
    """

    def __init__(self, nd: Discretization, options, backend: str):
        self.lay = hessian_layout(nd)
        self.linear = SPDSolver(self.lay, backend, options.threads)
        self.backend = self.linear.backend
        self.reuse = options.reuse_factorization
        C = nd.material.stiffness(nd.dim)
        self.elastic = (C, assemble_hessian(self.lay, None, C))
        self.costs = {"factored": False}
        self.data = self.elastic[1]

    def update(self, st: State) -> None:
        self.data = assemble_hessian(self.lay, st.plastic, st.tangent, self.elastic)

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

    def __init__(self, nd: Discretization, units, options, cdofs: np.ndarray):
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
    grad: np.ndarray | None
    energy: float
    #: the strains of the plastic elements (``disc.strain(u)[plastic]``), kept by
    #: :func:`~elastoplast.solvers.newton.evaluate` so that the tangents need no second
    #: product ``B u`` (None: computed again)
    eps_plastic: np.ndarray | None = None

    def with_tangent(self, disc: Discretization) -> "State":
        """The same iterate with its consistent tangents (computed on the plastic elements only)."""
        if self.tangent is not None:
            return self
        eps = disc.strain(self.u)[self.plastic] if self.eps_plastic is None else self.eps_plastic
        state = None if disc.state is None else disc.state.rows(self.plastic)
        return replace(self, tangent=consistent_tangent(disc.material, eps, state)[2])
