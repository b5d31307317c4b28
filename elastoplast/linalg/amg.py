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
  nodes as near-null space (:data:`AMG_SETTINGS`), one V-cycle as preconditioner,
  refreshed for a new matrix of the same pattern on its kept prolongators
  (:meth:`AMG.refresh`);
* :class:`BorderedSystem`: the matrix ``[[A, b], [b^T, c]]`` of a stiffness
  coupled to one extra unknown (the rigid body's displacement U, coupled to
  every contact dof), preconditioned by block elimination of U with the AMG
  V-cycle ``M`` in place of ``A^{-1}`` (:meth:`BorderedSystem.precondition`);
* :func:`pcg`: preconditioned conjugate gradients.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.discretize import Discretization
from elastoplast.linalg.blocks import (BlockLayout, add_in_place, block_rows, block_transpose, bsr, changed_blocks,
                                      constrain, constrain_again, near_null_space)


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


# ----------------------------------------------------------------------------
# multigrid and Krylov
# ----------------------------------------------------------------------------


#: pyamg's settings of :class:`AMG`, each changed alone and measured (a one-off sweep,
#: 2026-12-01, on a machine shared with other jobs) on the elastic stiffness that
#: ``benchmarks/scale/elastic.py`` solves: CPU s of set-up + CG to 1e-10, one BLAS
#: thread, at 118k / 1.03M tetrahedra. The previous settings (theta = 0,
#: Jacobi-smoothed prolongators weighted by an eigenvalue estimate, symmetric block
#: Gauss-Seidel) 2.5 / 27-29 s, 30 / 40 CG iterations; strength theta = 0.02
#: 2.1-2.4 / 25.8 s, 26 / 33 iterations (theta = 0.05: 20 iterations at 1M, but an
#: operator complexity of 3.1 and 34 s); then the prolongator's weight from row sums
#: ("local") instead of the eigenvalue estimate (15 of the 90 fine matrix-vector
#: products of a set-up each): 40% less set-up at 118k for one iteration more (2.2 s,
#: 27 its; 1M: 4.8 s set-up, 26.2 s in all, 36 its);
#: Jacobi, block Jacobi or Chebyshev smoothing 3.1-4.7 s (75-95 iterations), forward
#: then backward Gauss-Seidel (half the sweeps, 41 iterations) 2.3 s; naive aggregation
#: or evolution strength 4.3-6.5 s (operator complexity 3.5-3.9); a coarse grid of
#: 2000 block rows instead of 500 3.3-3.8 s (its LU dominates a V-cycle); float32
#: levels 12% faster, not taken (a preconditioner that is not symmetric to
#: working precision); improving the candidates by Gauss-Seidel 0.3 s more set-up
#: for one iteration less.
AMG_SETTINGS = {
    "strength": ("symmetric", {"theta": 0.02}),
    "smooth": ("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
    "presmoother": ("block_gauss_seidel", {"sweep": "symmetric"}),
    "postsmoother": ("block_gauss_seidel", {"sweep": "symmetric"}),
    "improve_candidates": None,
    "max_coarse": 500,
    "coarse_solver": "splu",
}


class AMG:
    """One smoothed-aggregation hierarchy (pyamg) of a BSR matrix; ``apply(r)``
    is one V-cycle, a symmetric positive definite approximation of ``A^{-1}``.

    The rigid-body motions of the nodes are the near-null space; the rest is
    :data:`AMG_SETTINGS`. :meth:`refresh` lets the hierarchy serve a new matrix of
    the same pattern (a new tangent, a new face) for a fraction of a set-up.
    """

    def __init__(self, A: sp.bsr_matrix, B: np.ndarray, **kwargs):
        import pyamg

        t0 = time.process_time()
        self.settings = {**AMG_SETTINGS, **kwargs}
        self.hierarchy = pyamg.smoothed_aggregation_solver(A, B=B, **self.settings)
        self.setup_time = time.process_time() - t0  # CPU seconds: the reuse policy compares costs, not load
        self.refresh_time = 0.0

    def apply(self, r: np.ndarray) -> np.ndarray:
        """One V-cycle from zero on ``A x = r``: what pyamg's ``aspreconditioner`` computes,
        without the two fine-level residuals its ``solve`` adds around the cycle (``b - A x``
        before it, at ``x = 0``, and after it, for a tolerance a preconditioner never reads):
        two of a cycle's seven fine-level matrix passes (symmetric Gauss-Seidel before and
        after, the residual). Measured on the elastic stiffness at 375k tetrahedra (one BLAS
        thread): 0.25 -> 0.18 s per application; the same vector to the last bit."""
        levels = self.hierarchy.levels
        x = np.zeros_like(r, dtype=float)
        if len(levels) == 1:
            return np.asarray(self.hierarchy.coarse_solver(levels[0].A, np.asarray(r, dtype=float))).ravel()
        self.hierarchy._MultilevelSolver__solve(0, x, np.asarray(r, dtype=float), "V")
        return x

    def refresh(self, A: sp.bsr_matrix, galerkin: bool = True) -> None:
        """Serve ``A`` (the pattern and near-null space of the matrix of the set-up)
        with the kept aggregates and prolongators ``P``: the finest level becomes
        ``A`` and, with ``galerkin``, each coarse operator ``R A P`` again, updated
        by ``R (A - A_old) P`` where the blocks of ``A - A_old`` are nonzero (the
        plastic elements and the changed face: a few percent of the blocks); then
        the smoothers and the coarsest factorisation anew."""
        from pyamg.multilevel import coarse_grid_solver
        from pyamg.relaxation.smoothing import change_smoothers

        t0 = time.process_time()
        levels = self.hierarchy.levels
        delta = changed_blocks(levels[0].A, A) if galerkin else None
        levels[0].A = A
        if delta is not None and delta.nnz == 0:  # the same values: the hierarchy serves as it is
            self.refresh_time = time.process_time() - t0
            return
        if delta is not None:
            for fine, coarse in zip(levels[:-1], levels[1:]):
                delta = fine.R @ (delta @ fine.P)
                if not add_in_place(coarse.A, delta):
                    coarse.A = (coarse.A + delta).tobsr(blocksize=coarse.A.blocksize)
            self.hierarchy.coarse_solver = coarse_grid_solver(self.settings["coarse_solver"])
        change_smoothers(self.hierarchy, self.settings["presmoother"], self.settings["postsmoother"])
        self.refresh_time = time.process_time() - t0


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
        self._z = None

    def _eliminate(self) -> None:
        """``z = M b`` and ``s``, at the first preconditioning: a face solve that its Galerkin
        start already answers (no CG iteration) needs neither (one V-cycle saved; at 375k
        tetrahedra 5 of Uzawa's 24 new faces in its first projection)."""
        self._z = self.amg.apply(self.b)
        s = self.c - float(self.b @ self._z)
        self._s = s if s > 1e-3 * self.c else 0.5 * self.c

    @property
    def z(self) -> np.ndarray:
        if self._z is None:
            self._eliminate()
        return self._z

    @property
    def s(self) -> float:
        if self._z is None:
            self._eliminate()
        return self._s

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


#: how a kept hierarchy serves a new matrix or face (:meth:`AMG.refresh`): "galerkin"
#: (new finest level and coarse operators on the kept prolongators), "fine" (new finest
#: level only) or None (the hierarchy as set up). Measured on Newton to KKT 1e-8 on the
#: default problem: at 118k tetrahedra 102 / 77 / 52 CG iterations in all and 4 / 1 / 1
#: set-ups (None / "fine" / "galerkin"); at 1.03M, "galerkin" 66 CG iterations and one
#: set-up against 182 and five with None (benchmarks/scale/elastic.md).
REFRESH = "galerkin"

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

    A hierarchy serves every face of the matrix it was set up on (Uzawa's metric:
    one set-up per run). For a new matrix (Newton's next tangent) it is kept while
    a new one would not pay for itself: with ``rate`` the log residual reduction
    per CG iteration with the current hierarchy and ``rate_fresh`` the one
    measured when it was built, a new one is set up when the iterations it would
    save on a solve to ``rtol``, ``log(rtol) (1/rate - 1/rate_fresh)``, cost more
    than its set-up time less what serving the new matrix costs (``reuse=False``:
    a new one for every solve). A kept hierarchy serves each new matrix or face through
    :meth:`AMG.refresh` (``refresh``, :data:`REFRESH`): its finest level and, with
    "galerkin", its coarse operators are the new matrix's; only the aggregates
    and prolongators are the old ones.
    """

    def __init__(self, lay: BlockLayout, free_index: np.ndarray, cdofs: np.ndarray, data: np.ndarray,
                 weight: float = 0.0, reuse: bool = True, recycle: int = 0, refresh: str | None = REFRESH):
        self.lay, self.free_index, self.weight, self.reuse = lay, free_index, float(weight), reuse
        self.refresh = refresh
        self.recycle = recycle
        # the kept solutions, in place: their raw values, the same masked to the face of
        # ``_for`` and H times those (columns, Fortran order); ``_valid`` the columns
        # of V and HV that are ``_for``'s. Measured at 1.03M tetrahedra: two stacks of
        # eight 1.5M-vectors a solve (0.1-0.2 s) no more
        self._raw = self._V = self._HV = None
        self._kept = self._slot = 0
        self._for: BorderedSystem | None = None
        self._for_face: tuple | None = None  # (matrix values, c, fixed dofs) of _for's face (_carry_over)
        self._crow_of: np.ndarray | None = None  # each dof's contact row, -1 elsewhere (_crow_index)
        self._valid: set[int] = set()
        self.ec = np.zeros(lay.n_dofs)
        self.ec[free_index[cdofs]] = 1.0
        self.crows = free_index[cdofs]
        self.near_null = near_null_space(lay)
        self.transpose = block_transpose(lay)
        self._plain: tuple | None = None
        self.amg: AMG | None = None
        self.version = 0  # counts the matrices (set_matrix)
        self.built_on: int | None = None  # the version of the matrix of the hierarchy's set-up
        self.rate_fresh = self.rate = 0.0
        self.iteration_time = 0.0
        self.setups = self.refreshes = 0
        self.plain_rate = False  # rate_fresh measured by solve_plain (until a face solve sets up anew)
        self.set_matrix(data)

    def set_matrix(self, data: np.ndarray) -> None:
        """A new ``K`` (block values on the layout's pattern); the hierarchy is kept."""
        if data is not getattr(self, "data", None):  # new values (the same array: a new weight only)
            self.version += 1
        self.data = data
        self._cached = None
        self._K_contact = None
        self._faces = []  # (matrix values, fixed dofs, face values) of the last two faces (_constrain)
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

    def matvec_contact(self, x: np.ndarray) -> np.ndarray:
        """``(H x)`` at the contact variables alone (the rows of :meth:`matvec` at ``cdofs``):
        the contact rows of ``K`` (kept in CSR while the matrix is the same), a few
        percent of a full product. Uzawa's projection needs only these rows for its
        multipliers: measured at 118k tetrahedra, the full products of the projection
        were 0.6 s of a 19.5 s run."""
        if self._K_contact is None:
            self._K_contact = block_rows(self.lay, self.data, self.crows)
        xf = self.lay.embed(x[:-1], self.free_index)
        return self._K_contact @ xf + self.Kec[self.crows] * x[-1]

    def _stale(self, rtol: float) -> bool:
        if self.amg is None or not self.reuse:
            return True
        if self.version == self.built_on:
            # a new face of the matrix the hierarchy was set up on: the refreshed hierarchy
            # is that matrix's with other Dirichlet rows, as good as a new one. The rule
            # below, rates of CG solves of different right-hand sides compared, set up 3
            # hierarchies for Uzawa's one metric at 118k-1.03M tetrahedra (the solves of
            # a projection's first face, with a right-hand side in U alone, take 15 CG
            # iterations on a fresh hierarchy too); this one sets up one
            return False
        if self.rate_fresh >= 0.0:
            return True
        goal = np.log(max(rtol, 1e-16))
        return (goal / self.rate - goal / self.rate_fresh) * self.iteration_time \
            > self.amg.setup_time - self.amg.refresh_time

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
        A = bsr(self.lay, self._constrain(fixed_dofs))
        if rebuild:
            self.amg = self._cached = None  # free the old hierarchy first
            self.amg = AMG(A, self.near_null)
            self.built_on = self.version
            self.setups += 1
        elif self.refresh:
            self.amg.refresh(A, galerkin=self.refresh == "galerkin")
            self.refreshes += 1
        system = BorderedSystem(A, self.amg, np.where(fixed_dofs, 0.0, self.Kec), self.c)
        self._cached = (self.data, fixed_dofs, system)
        return system, rebuild

    def _constrain(self, fixed_dofs: np.ndarray) -> np.ndarray:
        """The block values of the face ``fixed_dofs`` (:func:`constrain`): the last two faces'
        arrays of the current matrix are kept, and the older one (no longer the hierarchy's
        finest level nor the cached system's) is rewritten for the new face by
        :func:`constrain_again` instead of a new copy of every block."""
        faces = [f for f in self._faces if f[0] is self.data]
        if len(faces) == 2:
            _, was, out = faces.pop(0)
            out = constrain_again(self.lay, self.data, out, was, fixed_dofs, self.transpose)
        else:
            out = constrain(self.lay, self.data, fixed_dofs, self.transpose)
        faces.append((self.data, fixed_dofs.copy(), out))
        self._faces = faces
        return out

    def _solve(self, fixed, rhs, rtol, x0, max_iter):
        lay = self.lay
        if x0 is None and not np.any(rhs[~fixed]):  # nothing to solve: x = 0 exactly
            return np.zeros_like(rhs, dtype=float), {"amg_setup": False, "cg_iterations": 0, "cg_residual": 0.0,
                                                     "setup_time": 0.0, "solve_time": 0.0}
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
        elif self._kept:
            start, initial = self._galerkin_start(system, r, fixed_dofs)
            initial /= norm_r
        x, its, ok = pcg(system.matvec, system.precondition, r, start, rtol, max_iter)
        if self.recycle:
            self._keep(x)
        t2, c2 = time.perf_counter(), time.process_time()
        reached = float(np.linalg.norm(r - system.matvec(x)) / norm_r)
        if its >= RATE_MIN_ITERATIONS or (rebuild and its):
            # reduction per iteration from CG's own start (a Galerkin start is not CG's merit);
            # a solve of one or two iterations says little (CG's residual need not fall monotonically)
            self.iteration_time = (c2 - c1) / its
            self.rate = min(np.log(max(reached, 1e-16) / max(initial, 1e-16)) / its, -1e-3)
            if rebuild:
                self.rate_fresh = self.rate
                self.plain_rate = False
        out = np.append(x[:-1][self.free_index], x[-1])
        out[fixed] = 0.0
        return out, {"amg_setup": rebuild, "cg_iterations": its, "cg_residual": reached,
                     "setup_time": t1 - t0, "solve_time": t2 - t1}

    def _keep(self, x: np.ndarray) -> None:
        """Keep ``x`` among the last ``recycle`` solutions (overwriting the oldest)."""
        if self._raw is None or self._raw.shape[0] != x.size:
            shape = (x.size, self.recycle)
            self._raw, self._V, self._HV = (np.empty(shape, order="F") for _ in range(3))
            self._kept = self._slot = 0
            self._valid = set()
        self._raw[:, self._slot] = x
        self._valid.discard(self._slot)
        self._slot = (self._slot + 1) % self.recycle
        self._kept = min(self._kept + 1, self.recycle)

    def _galerkin_start(self, system: BorderedSystem, r: np.ndarray, fixed_dofs: np.ndarray) -> tuple[np.ndarray, float]:
        """``x0 = V c`` with ``(V^T H V) c = V^T r`` over the kept solutions (zero on the
        fixed dofs), and ``|r - H x0|``.

        ``H v`` of a kept solution is kept too while the face system is the same
        object (Uzawa's metric and, once the contact set settles, its face do not
        change): one product per solve instead of one per kept solution."""
        if self._for is not system:
            self._valid = self._carry_over(system, fixed_dofs)
            self._for, self._for_face = system, (self.data, self.c, fixed_dofs.copy())
        k = self._kept
        for j in range(k):
            if j not in self._valid:
                self._V[:, j] = self._raw[:, j]
                self._V[:-1, j][fixed_dofs] = 0.0
                self._HV[:, j] = system.matvec(self._V[:, j])
                self._valid.add(j)
        V, HV = self._V[:, :k], self._HV[:, :k]
        coef = np.linalg.lstsq(V.T @ HV, V.T @ r, rcond=1e-12)[0]
        return V @ coef, float(np.linalg.norm(r - HV @ coef))

    def _carry_over(self, system: BorderedSystem, fixed_dofs: np.ndarray) -> set[int]:
        """The kept columns' ``V`` and ``H V`` for a new face of the same matrix from the last
        face's, where the two faces differ in contact rows only (Uzawa's active-set steps):
        with ``v`` zero on the fixed dofs, ``H v`` is ``K v_u + K e_c v_U`` masked to the free
        rows (bordered by ``b . v_u + c v_U``), and ``K v_u`` changes by ``K`` times the change
        of ``v`` at the changed dofs, whose columns are the contact rows of ``K`` (symmetric);
        the rows freed anew get their product from those rows. One product by the contact
        columns for all columns instead of a product by ``H`` each (8 a new face; measured
        at 375k tetrahedra: 3.1 s of Uzawa's 64 s). Equal to the products to rounding.
        Returns the columns that are valid for ``system`` (none when it cannot carry them)."""
        face = self._for_face
        if self._for is None or face is None or face[0] is not self.data or face[1] != self.c or not self._valid:
            return set()
        was = face[2]
        changed = np.flatnonzero(was != fixed_dofs)
        rows = self._crow_index()[changed]
        if np.any(rows < 0):
            return set()
        if self._K_contact is None:
            self._K_contact = block_rows(self.lay, self.data, self.crows)
        cols = sorted(self._valid)
        Kc = self._K_contact[rows]  # K's rows (= columns) of the changed dofs
        freed = changed[~fixed_dofs[changed]]
        K_freed, Kec_freed = self._K_contact[rows[~fixed_dofs[changed]]], self.Kec[freed]
        for j in cols:  # column by column: no copies of all kept columns at once
            v, hv = self._V[:, j], self._HV[:, j]
            old = v[changed]
            # the rows freed anew: their products K v_u + Kec v_U (masked to zero before)
            q = K_freed @ v[:-1] + Kec_freed * v[-1]
            v[:] = self._raw[:, j]
            v[:-1][fixed_dofs] = 0.0
            hv[freed] = q
            hv[:-1] += Kc.T @ (v[changed] - old)
            hv[:-1][fixed_dofs] = 0.0
            hv[-1] = system.b @ v[:-1] + system.c * v[-1]
        return set(cols)

    def _crow_index(self) -> np.ndarray:
        """For each dof its row in the contact rows, -1 elsewhere."""
        if self._crow_of is None:
            self._crow_of = np.full(self.lay.n_dofs + 1, -1, dtype=np.int64)
            self._crow_of[self.crows] = np.arange(self.crows.size)
        return self._crow_of[:-1]

    def solve_plain(self, rhs: np.ndarray, rtol: float) -> np.ndarray:
        """``K x = rhs`` on the free dofs alone (no contact dof fixed, no U), by CG
        with the current hierarchy (a new one if there is none).

        A hierarchy set up here is the face solves' too: its rate is measured on
        these solves as on a face solve's, so the first face (no contact dof fixed:
        the same matrix) serves on it instead of setting up another (later faces
        still set up anew when :meth:`_stale` says so). Uzawa's set-up (the weight's
        estimate and the start's projection), measured on the default 3D problem:
        3.0 -> 2.4 s at 118k tetrahedra, 12.4 -> 9.2 s at 375k (one AMG set-up less,
        about 5 s at 1.03M)."""
        lay = self.lay
        if self._plain is None or self._plain[0] is not self.data:
            self._plain = (self.data, bsr(lay, constrain(lay, self.data, ~lay.free, self.transpose)))
        A = self._plain[1]
        rebuild = self.amg is None
        if rebuild:
            with one_blas_thread():
                self.amg = AMG(A, self.near_null)
            self.built_on = self.version
            self.setups += 1
        system = BorderedSystem(A, self.amg)
        b = lay.embed(rhs, self.free_index)
        c1 = time.process_time()
        with one_blas_thread():
            x, its, _ = pcg(system.matvec, system.precondition, b, None, rtol, 1000)
        c2 = time.process_time()
        if its >= RATE_MIN_ITERATIONS and (rebuild or self.plain_rate):
            norm_b = max(float(np.linalg.norm(b)), np.finfo(float).tiny)
            reached = float(np.linalg.norm(b - system.matvec(x)) / norm_b)
            rate = min(np.log(max(reached, 1e-16)) / its, -1e-3)
            self.iteration_time = (c2 - c1) / its
            self.rate = rate
            # the first measurements of a new hierarchy (the worst of them: a later face solve
            # then compares with what the hierarchy does on any right-hand side)
            self.rate_fresh = rate if rebuild else max(self.rate_fresh, rate)
            self.plain_rate = True
        return x[self.free_index]

    def release(self) -> None:
        self._faces = []
        self.amg = self._cached = self._plain = self.built_on = None
        self._raw = self._V = self._HV = self._for = self._for_face = None
        self._kept = self._slot = 0
        self._valid = set()
