"""Sparse direct factorisations of symmetric positive definite matrices, chosen by measurement.

:func:`factorize_spd` factors a matrix once and returns its solve (SuperLU, CHOLMOD through cholespy,
MKL PARDISO through pypardiso, QDLDL); :class:`SPDSolver` refactors matrices of one sparsity pattern,
PARDISO's symbolic analysis done once."""

from __future__ import annotations

import ctypes
import functools
import os
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from elastoplast.errors import InputError

Solve = Callable[[np.ndarray], np.ndarray]


def factor_splu(G: sp.spmatrix) -> Solve:
    lu = spla.splu(sp.csc_matrix(G), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    return lu.solve


def factor_cholespy(G: sp.spmatrix) -> Solve:
    import cholespy

    A = sp.csc_matrix(G)
    A.sort_indices()
    chol = cholespy.CholeskySolverD(A.shape[0], A.indptr.astype(np.int32), A.indices.astype(np.int32),
                                    np.ascontiguousarray(A.data), cholespy.MatrixType.CSC)

    def solve(b: np.ndarray) -> np.ndarray:
        b = np.ascontiguousarray(b, dtype=float)
        x = np.empty_like(b)
        chol.solve(b, x)
        return x

    return solve


def factor_pypardiso(G: sp.spmatrix) -> Solve:
    import pypardiso

    A = sp.triu(G, format="csr")  # mtype 2 (real SPD) reads the upper triangle
    A.sort_indices()
    ps = pypardiso.PyPardisoSolver(mtype=2)
    ps.set_statistical_info_off()
    ps.factorize(A)
    return lambda b: ps.solve(A, np.asarray(b, dtype=float))


def factor_qdldl(G: sp.spmatrix) -> Solve:
    import qdldl

    f = qdldl.Solver(sp.triu(G, format="csc"), upper=True)

    def solve(b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        if b.ndim == 1:
            return f.solve(b)
        return np.column_stack([f.solve(np.ascontiguousarray(c)) for c in b.T])

    return solve


#: sparse factorisations of G, each ``G -> solve(b)`` for one or several right-hand sides
FACTORIZATIONS: dict[str, Callable[[sp.spmatrix], Solve]] = {
    "splu": factor_splu,
    "cholespy": factor_cholespy,
    "pypardiso": factor_pypardiso,
    "qdldl": factor_qdldl,
}


#: "auto" choice, measured in benchmarks/uzawa/components.md: on the 3D sphere with
#: 52,728 tetrahedra (G: 24,375 rows, 958k nonzeros) PARDISO factors 4.8-8.1x faster than
#: SuperLU and CHOLMOD (cholespy), which decides the setup; below about half a million
#: nonzeros cholespy is the fastest and PARDISO's fixed cost (0.3-2 s to locate and start
#: MKL) dominates. Each list is tried in order among the installed packages.
AUTO_LARGE_NNZ = 500_000


AUTO_ORDER = {"small": ("cholespy", "splu"), "large": ("pypardiso", "cholespy", "splu")}


def factorize_spd(G: sp.spmatrix, method: str = "auto") -> Solve:
    """Factor G once; returns ``solve(b) = G^{-1} b`` (b of shape (n,) or (n, m))."""
    if method in ("auto", "amg"):  # "amg" never factors: a direct solve where one is asked for
        for name in AUTO_ORDER["large" if G.nnz >= AUTO_LARGE_NNZ else "small"]:
            try:
                return FACTORIZATIONS[name](G)
            except ImportError:
                continue
    if method not in FACTORIZATIONS:
        raise InputError("factorization", f"unknown factorisation {method!r} (choose from {sorted(FACTORIZATIONS)} or 'auto')")
    return FACTORIZATIONS[method](G)


@functools.cache
def mkl_runtime() -> str:
    """Path of MKL's runtime as found by pypardiso at import (its search of
    ``sys.prefix`` takes seconds; new solver objects reuse the result)."""
    import pypardiso

    return pypardiso.ps.libmkl._name


class SPDSolver:
    """Factorisation of symmetric positive definite matrices of one pattern.

    PARDISO (``mtype = 2``, upper triangle) does its symbolic analysis once
    and only refactorises numerically afterwards; SuperLU is the fallback. ``lay``
    is the pattern: ``size``, CSR ``indptr`` and ``indices`` of the upper triangle,
    and the positions ``diag`` of the diagonal in it
    (:class:`~elastoplast.solvers.hessian.HessianLayout`).
    """

    def __init__(self, lay, backend: str = "auto", threads: int | None = None):
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

        os.environ.setdefault("PYPARDISO_MKL_RT", mkl_runtime())
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
                self.lu = spla.splu(full)  # COLAMD: 41 s at 111k tetrahedra, MMD_AT_PLUS_A > 9 min
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


@functools.cache
def pardiso_available() -> bool:
    try:
        SPDSolver._pardiso(None)
    except Exception:  # not installed, or its internals moved
        return False
    return True


#: regularisation of the row-normalised Gram matrix A A^T (diagonal 1): redundant
#: traction rows make it singular; iterative refinement removes the regularisation's bias
GRAM_REGULARISATION = 1e-10


def project_affine(A: sp.csc_matrix, b: np.ndarray, x: np.ndarray, max_refine: int = 10) -> tuple[np.ndarray, float]:
    """Minimum-norm correction of x onto ``A x = b`` (b in the range of A).

    Rows are normalised, ``K = A A^T + eps I`` is factored once and refined:
    ``x <- x + A^T K^{-1} (b - A x)``. Every correction lies in the range of A^T,
    so the limit is the minimum-norm correction even when rows are redundant
    (K singular without eps); each sweep shrinks the residual by
    ``eps / (sigma^2 + eps)`` for every nonzero singular value sigma of A.
    Returns ``(x, max |b - A x| / max_i sum_j |A_ij x_j|)`` after the last sweep. A
    solver's answer out of range (overflowing, not finite) gives a residual that is not
    finite, with no floating-point warning: the static certificate refuses it and says so.
    """
    A = sp.csr_matrix(A)
    norms = np.sqrt(np.asarray(A.multiply(A).sum(axis=1)).ravel())
    norms[norms == 0] = 1.0
    As = sp.diags(1.0 / norms) @ A
    bs = b / norms
    solve = factorize_spd((As @ As.T + GRAM_REGULARISATION * sp.eye(A.shape[0])).tocsc())
    x = x.copy()
    last = np.inf
    with np.errstate(all="ignore"):
        for _ in range(max_refine):
            r = bs - As @ x
            size = np.abs(r).max(initial=0.0)
            if not size < 0.5 * last:  # no progress, or not finite
                break
            x += As.T @ solve(r)
            last = size
        scale = max((abs(As) @ np.abs(x)).max(initial=0.0), np.finfo(float).tiny)
        residual = float(np.abs(bs - As @ x).max(initial=0.0) / scale)
    return x, residual if np.isfinite(residual) else np.inf
