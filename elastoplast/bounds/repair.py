"""Exact repair of a solver's lower-bound field: the equality rows restored to round-off.

A conic solver meets the program's equality rows only to its tolerance. The repair
projects the unknowns onto the affine set of the rows (a Gram system, refined
iteratively) while keeping the contact tractions non-negative exactly, so that the field
handed to the static certificate is admissible up to round-off."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from elastoplast.bounds.program import Program

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
    from elastoplast.linalg.direct import factorize_spd

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


def repair_static(prog: Program, x: np.ndarray, max_rounds: int = 10) -> tuple[np.ndarray, float, int]:
    """Project the solver's ``(tau_hat, lam_hat)`` exactly onto the equality rows,
    keeping ``lam >= 0`` exactly.

    Pressures that are not positive are fixed at 0 (their columns dropped) and the
    rest is projected; any pressure the correction drives negative joins them and
    the projection is repeated from there, so the answer has ``lam >= 0`` exactly
    and satisfies the rows to round-off. In limit mode F is held at the solver's
    value. Returns ``(x, relative residual, number of pressures fixed at zero)``.
    """
    x = x.copy()
    lam = np.zeros(x.size, dtype=bool)
    lam[prog.cols["lam"]] = True
    movable = np.zeros(x.size, dtype=bool)
    movable[prog.cols["tau"]] = True
    movable[prog.cols["lam"]] = True
    A_eq = prog.A[: prog.n_eq]
    zero = lam & (x <= 0.0)
    res = np.inf
    for _ in range(max_rounds):
        x[zero] = 0.0
        cols = movable & ~zero
        rhs = prog.b[: prog.n_eq] - A_eq[:, ~cols] @ x[~cols]
        x[cols], res = project_affine(A_eq[:, cols], rhs, x[cols])
        neg = lam & (x < 0.0)
        if not neg.any():
            break
        zero |= neg
    return x, res, int(zero.sum())
