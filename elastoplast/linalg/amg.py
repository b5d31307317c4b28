"""The iterative linear-algebra path: node-block assembly, smoothed-aggregation AMG, CG.

Direct factorisations of the stiffness grow like ``n^{4/3}``-``n^2`` in time and
fill in 3D (PARDISO: 200 s and 7.2 GB for one factorisation at 1.03M
tetrahedra); conjugate gradients preconditioned by algebraic multigrid grow
about linearly. This module holds what Newton's tangent systems and Uzawa's
metric need for that path:

* :class:`BlockLayout`: the stiffness-type matrices ``sum_T |T| B_T^T D_T B_T``
  stored as BSR with one ``d x d`` block per pair of neighbouring nodes, over
  every dof (fixed ones included, as identity-like rows): the discretisation's
  :class:`~elastoplast.fem.assembly.Layout`, assembled element by element in
  chunks by :func:`~elastoplast.fem.assembly.assemble` without a global copy of
  per-element matrices: memory is the matrix, the shape gradients
  ``(n_el, d+1, d)`` and one ``int32`` slot per element block;
* :func:`constrain`: Dirichlet rows and columns (the clamped dofs and the
  active contact dofs of a Newton face) replaced by their diagonal;
* :class:`AMG`: pyamg's smoothed aggregation with the rigid-body motions of the
  nodes as near-null space, one V-cycle as preconditioner;
* :class:`BorderedSystem`: the matrix ``[[A, b], [b^T, c]]`` of a stiffness
  coupled to one extra unknown (the rigid body's displacement U, coupled to
  every contact dof), preconditioned by block elimination of U with the AMG
  V-cycle ``M`` in place of ``A^{-1}`` (:meth:`BorderedSystem.precondition`);
* :func:`pcg`: preconditioned conjugate gradients.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field, fields

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.assembly import Layout, rigid_motions
from elastoplast.fem.discretize import Discretization


def one_blas_thread():
    """A context with one BLAS thread. Measured on the 3D sphere (52,728 tetrahedra,
    Newton with AMG-CG, 2 cores shared with other jobs): 3.9 s of CPU against 13.6 s
    with OpenBLAS's default two threads, whose level-1 kernels (the dot products of
    CG and of pyamg's cycle) spin-wait for a busy core."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - declared as a dependency
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


@dataclass(frozen=True)
class BlockLayout(Layout):
    """The :class:`~elastoplast.fem.assembly.Layout` of a discretisation with what
    the iterative path adds: ``free`` marks the free dofs (``node * d +
    component``) and ``points`` are the nodes in the layout's length unit (for
    the near-null space)."""

    free: np.ndarray
    points: np.ndarray = field(repr=False)

    def embed(self, x_free: np.ndarray, free_index: np.ndarray) -> np.ndarray:
        """A vector on the free dofs as a vector on every dof (zeros at fixed ones)."""
        out = np.zeros(self.n_dofs)
        out[free_index] = x_free
        return out


def block_layout(disc: Discretization, length: float = 1.0) -> BlockLayout:
    """The block pattern of ``disc``'s mesh (``disc.layout``); nodes in units of ``length``.

    ``length`` is the unit of a nondimensionalised discretisation
    (:class:`~elastoplast.fem.discretize.Units`): ``disc.B`` and the gradients
    of ``nondimensionalize(disc)`` are the original ones times ``length``.
    """
    lay = disc.layout
    free = np.zeros(lay.n_dofs, dtype=bool)
    free[disc.free] = True
    return BlockLayout(**{f.name: getattr(lay, f.name) for f in fields(Layout)}, free=free,
                       points=disc.mesh.points / length)


def constrain(lay: BlockLayout, data: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Rows and columns of the ``fixed`` dofs (bool, every dof) zeroed, their diagonal kept."""
    keep = (~fixed).reshape(lay.n_nodes, lay.dim).astype(float)
    out = data * keep[lay.brow][:, :, None]
    out *= keep[lay.indices][:, None, :]
    nodes, comps = np.nonzero(fixed.reshape(lay.n_nodes, lay.dim))
    out[lay.diag[nodes], comps, comps] = data[lay.diag[nodes], comps, comps]
    return out


def bsr(lay: BlockLayout, data: np.ndarray) -> sp.bsr_matrix:
    """The BSR matrix of block values ``data`` on the layout's pattern."""
    n = lay.n_dofs
    return sp.bsr_matrix((data, lay.indices, lay.indptr), shape=(n, n))


def near_null_space(lay: BlockLayout) -> np.ndarray:
    """Rigid-body motions of the nodes ``(n_dofs, 3 or 6)``: the near-null space of
    every stiffness-type matrix here (the clamped body has none exactly, but
    they are the smooth, low-energy modes multigrid must coarsen well).
    Rotations are scaled to the size of the translations."""
    modes = rigid_motions(lay.points)
    return modes / np.linalg.norm(modes, axis=0)


# ----------------------------------------------------------------------------
# multigrid and Krylov
# ----------------------------------------------------------------------------


class AMG:
    """One smoothed-aggregation hierarchy (pyamg) of a BSR matrix; ``apply(r)``
    is one V-cycle, a symmetric positive definite approximation of ``A^{-1}``.

    Measured choices (benchmarks/scale/README.md): the rigid-body motions as
    near-null space, symmetric strength with theta = 0, symmetric block
    Gauss-Seidel smoothing.
    """

    def __init__(self, A: sp.bsr_matrix, B: np.ndarray, **kwargs):
        import pyamg

        t0 = time.process_time()
        kwargs.setdefault("improve_candidates", None)
        self.hierarchy = pyamg.smoothed_aggregation_solver(A, B=B, max_coarse=500, coarse_solver="splu", **kwargs)
        self._M = self.hierarchy.aspreconditioner(cycle="V")
        self.setup_time = time.process_time() - t0  # CPU seconds: the reuse policy compares costs, not load

    def apply(self, r: np.ndarray) -> np.ndarray:
        return self._M @ r


@dataclass
class BorderedSystem:
    """``[[A, b], [b^T, c]]``: a stiffness ``A`` (every dof) bordered by one extra
    unknown; ``b = None`` is ``A`` alone.

    The preconditioner is the block factorisation ``L diag(A, s) L^T``
    (``L = [[I, 0], [z^T, 1]]``, ``z = A^{-1} b``, ``s = c - b^T z``) with the
    V-cycle ``M ~ A^{-1}`` in place of ``A^{-1}``:
    ``P [r; rho] = [M r - z t; t]``, ``t = (rho - z^T r) / s``, with ``z = M b``.
    ``P`` is symmetric positive definite for any SPD ``M`` and ``s > 0``; when the
    estimate ``c - b^T M b`` is not safely positive (a hierarchy kept from an
    earlier matrix can overestimate ``A^{-1}``) ``s = c / 2`` stands in. So CG on
    the bordered system costs about what it costs on ``A``.
    """

    A: sp.bsr_matrix
    amg: AMG
    b: np.ndarray | None = None
    c: float = 0.0

    def __post_init__(self) -> None:
        if self.b is not None:
            self.z = self.amg.apply(self.b)
            s = self.c - float(self.b @ self.z)
            self.s = s if s > 1e-3 * self.c else 0.5 * self.c

    @property
    def size(self) -> int:
        return self.A.shape[0] + (self.b is not None)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        if self.b is None:
            return self.A @ x
        n = self.A.shape[0]
        out = np.empty_like(x)
        out[:n] = self.A @ x[:n] + self.b * x[n]
        out[n] = self.b @ x[:n] + self.c * x[n]
        return out

    def precondition(self, r: np.ndarray) -> np.ndarray:
        if self.b is None:
            return self.amg.apply(r)
        n = self.A.shape[0]
        t = (r[n] - self.z @ r[:n]) / self.s
        return np.append(self.amg.apply(r[:n]) - self.z * t, t)


def pcg(matvec, precond, b: np.ndarray, x0: np.ndarray | None = None, rtol: float = 1e-10,
        max_iter: int = 1000) -> tuple[np.ndarray, int, bool]:
    """Conjugate gradients on ``A x = b`` preconditioned by ``precond``, from ``x0``
    (zero if None), until ``|b - A x|_2 <= rtol |b|_2``; returns ``(x, iterations, converged)``."""
    x = np.zeros_like(b) if x0 is None else x0.copy()
    r = b - matvec(x) if x0 is not None else b.copy()
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
# face systems in the variables y of the contact problems
# ----------------------------------------------------------------------------


#: CG iterations a solve needs before its residual reduction per iteration counts
RATE_MIN_ITERATIONS = 3


def contact_dofs(disc: Discretization) -> np.ndarray:
    """Free-dof number of the vertical dof of each contact node (rows of N)."""
    N = disc.N.tocsr()
    return N.indices[N.indptr[:-1]]


class FaceSystems:
    """Face systems of ``H = T^T diag(K, 0) T + w e_U e_U^T`` in the variables
    ``y = (u with w_i = u_{i,d} - U at the contact dofs, U)`` of Newton's method
    and of Uzawa's projection (``K`` the tangent stiffness or the metric G on
    the free dofs, ``w`` the metric's weight of U, 0 for Newton):

        H = [[K, K e_c], [e_c^T K, e_c^T K e_c + w]].

    A face fixes some contact variables; its system is ``[[A, b], [b^T, c]]``
    with ``A`` = K with the clamped and the fixed dofs as Dirichlet rows, ``b``
    = ``K e_c`` on the other rows, ``c = e_c^T K e_c + w``, solved by CG with
    :class:`BorderedSystem` and an AMG hierarchy of ``A``.

    A hierarchy serves later faces and matrices while a new one would not pay
    for itself: with ``rate`` the log residual reduction per CG iteration with
    the current hierarchy and ``rate_fresh`` the one measured when it was
    built, a new one is set up when the iterations it would save on a solve to
    ``rtol``, ``log(rtol) (1/rate - 1/rate_fresh)``, cost more than its set-up
    time (``reuse=False``: a new one for every solve).
    """

    def __init__(self, lay: BlockLayout, free_index: np.ndarray, cdofs: np.ndarray, data: np.ndarray,
                 weight: float = 0.0, reuse: bool = True, recycle: int = 0):
        self.lay, self.free_index, self.weight, self.reuse = lay, free_index, float(weight), reuse
        self.recycle = recycle
        self.previous: list[np.ndarray] = []
        self.ec = np.zeros(lay.n_dofs)
        self.ec[free_index[cdofs]] = 1.0
        self.near_null = near_null_space(lay)
        self.amg: AMG | None = None
        self.rate_fresh = self.rate = 0.0
        self.iteration_time = 0.0
        self.setups = 0
        self.set_matrix(data)

    def set_matrix(self, data: np.ndarray) -> None:
        """A new ``K`` (block values on the layout's pattern); the hierarchy is kept."""
        self.data = data
        self._cached = None
        self.K = bsr(self.lay, data)
        self.Kec = self.K @ self.ec
        self.c = float(self.ec @ self.Kec) + self.weight

    def diagonal(self) -> np.ndarray:
        """The diagonal of H (free dofs, then U)."""
        d = self.lay.dim
        diag = self.data[self.lay.diag][:, np.arange(d), np.arange(d)].ravel()
        return np.append(diag[self.free_index], self.c)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``H x`` for ``x`` on the free dofs and U."""
        xf = self.lay.embed(x[:-1], self.free_index)
        out = self.K @ xf + self.Kec * x[-1]
        return np.append(out[self.free_index], self.Kec @ xf + self.c * x[-1])

    def _stale(self, rtol: float) -> bool:
        if self.amg is None or not self.reuse:
            return True
        if self.rate_fresh >= 0.0:
            return True
        goal = np.log(max(rtol, 1e-16))
        return (goal / self.rate - goal / self.rate_fresh) * self.iteration_time > self.amg.setup_time

    def solve(self, fixed: np.ndarray, rhs: np.ndarray, rtol: float, x0: np.ndarray | None = None,
              max_iter: int = 1000) -> tuple[np.ndarray, dict]:
        """``H_FF x_F = rhs_F`` with ``x = 0`` on the ``fixed`` variables (bool over
        the free dofs and U; U is never fixed) to relative residual ``rtol``.

        Returns ``x`` and ``{"amg_setup", "cg_iterations", "cg_residual",
        "setup_time", "solve_time"}``."""
        with one_blas_thread():
            return self._solve(fixed, rhs, rtol, x0, max_iter)

    def _system(self, fixed_dofs: np.ndarray, rtol: float) -> tuple[BorderedSystem, bool]:
        """The face system of ``fixed_dofs`` and whether its hierarchy is new; the
        last one is kept while the matrix, the face and the hierarchy are the same."""
        rebuild = self._stale(rtol)
        cached = getattr(self, "_cached", None)
        if not rebuild and cached is not None and cached[0] is self.data and np.array_equal(cached[1], fixed_dofs) \
                and cached[2].amg is self.amg:
            return cached[2], False
        A = bsr(self.lay, constrain(self.lay, self.data, fixed_dofs))
        if rebuild:
            self.amg = self._cached = None  # free the old hierarchy first
            self.amg = AMG(A, self.near_null)
            self.setups += 1
        system = BorderedSystem(A, self.amg, np.where(fixed_dofs, 0.0, self.Kec), self.c)
        self._cached = (self.data, fixed_dofs, system)
        return system, rebuild

    def _solve(self, fixed, rhs, rtol, x0, max_iter):
        lay = self.lay
        fixed_dofs = ~lay.free
        fixed_dofs[self.free_index[fixed[:-1]]] = True
        t0 = time.perf_counter()
        system, rebuild = self._system(fixed_dofs, rtol)
        t1, c1 = time.perf_counter(), time.process_time()
        r = np.append(np.where(fixed_dofs, 0.0, lay.embed(rhs[:-1], self.free_index)), rhs[-1])
        norm_r = max(float(np.linalg.norm(r)), np.finfo(float).tiny)
        start, initial = None, 1.0
        if x0 is not None:
            start = np.append(np.where(fixed_dofs, 0.0, lay.embed(x0[:-1], self.free_index)), x0[-1])
            initial = np.linalg.norm(r - system.matvec(start)) / norm_r
        elif self.previous:
            start, initial = self._galerkin_start(system, r, fixed_dofs)
            initial /= norm_r
        x, its, ok = pcg(system.matvec, system.precondition, r, start, rtol, max_iter)
        if self.recycle:
            self.previous = (self.previous + [x])[-self.recycle:]
        t2, c2 = time.perf_counter(), time.process_time()
        reached = float(np.linalg.norm(r - system.matvec(x)) / norm_r)
        if its >= RATE_MIN_ITERATIONS or (rebuild and its):
            # reduction per iteration from CG's own start (a Galerkin start is not CG's merit);
            # a solve of one or two iterations says little (CG's residual need not fall monotonically)
            self.iteration_time = (c2 - c1) / its
            self.rate = min(np.log(max(reached, 1e-16) / max(initial, 1e-16)) / its, -1e-3)
            if rebuild:
                self.rate_fresh = self.rate
        out = np.append(x[:-1][self.free_index], x[-1])
        out[fixed] = 0.0
        return out, {"amg_setup": rebuild, "cg_iterations": its, "cg_residual": reached,
                     "setup_time": t1 - t0, "solve_time": t2 - t1}

    def _galerkin_start(self, system: BorderedSystem, r: np.ndarray, fixed_dofs: np.ndarray) -> tuple[np.ndarray, float]:
        """``x0 = V c`` with ``(V^T H V) c = V^T r`` over the kept solutions, and ``|r - H x0|``."""
        V = np.stack(self.previous, axis=1)
        V[:-1][fixed_dofs] = 0.0
        HV = np.stack([system.matvec(v) for v in V.T], axis=1)
        coef = np.linalg.lstsq(V.T @ HV, V.T @ r, rcond=1e-12)[0]
        return V @ coef, float(np.linalg.norm(r - HV @ coef))

    def solve_plain(self, rhs: np.ndarray, rtol: float) -> np.ndarray:
        """``K x = rhs`` on the free dofs alone (no contact dof fixed, no U), by CG
        with the current hierarchy (a new one if there is none)."""
        lay = self.lay
        A = bsr(lay, constrain(lay, self.data, ~lay.free))
        if self.amg is None:
            with one_blas_thread():
                self.amg = AMG(A, self.near_null)
            self.setups += 1
        system = BorderedSystem(A, self.amg)
        with one_blas_thread():
            x, _, _ = pcg(system.matvec, system.precondition, lay.embed(rhs, self.free_index), None, rtol, 1000)
        return x[self.free_index]

    def release(self) -> None:
        self.amg = None
