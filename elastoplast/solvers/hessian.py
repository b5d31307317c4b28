"""Newton's Hessian on a fixed sparsity pattern, and its two solvers: a direct factorisation refactored
numerically at every step, or AMG-preconditioned CG on the node-block matrix."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import consistent_tangent
from elastoplast.linalg.amg import (
    FaceSystems,
    assemble,
    block_layout,
    contact_dofs,
    pcg,
)
from elastoplast.linalg.direct import SPDSolver


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
    grad: np.ndarray
    energy: float

    def with_tangent(self, disc: Discretization) -> "State":
        """The same iterate with its consistent tangents (computed on the plastic elements only)."""
        if self.tangent is not None:
            return self
        eps = disc.strain(self.u)[self.plastic]
        return replace(self, tangent=consistent_tangent(disc.material, eps)[2])
