"""Exact repair of a solver's lower-bound field: the equality rows restored to round-off.

A conic solver meets the program's equality rows only to its tolerance. The repair
projects the unknowns onto the affine set of the rows
(:func:`~elastoplast.linalg.direct.project_affine`: a Gram system, refined
iteratively) while keeping the contact tractions non-negative exactly, so that the
field handed to the static certificate is admissible up to round-off."""

from __future__ import annotations

import numpy as np

from elastoplast.bounds.equilibrium.program import Program
from elastoplast.linalg.direct import project_affine


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
