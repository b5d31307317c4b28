"""Newton polishing of an approximate solution of (2.1).

Interior points identify the plastic elements and the contact set but leave
borderline elements about sqrt(gap) off. From such a start, a few
primal-dual active-set Newton steps on the displacement form (D) land on the
discrete solution to round-off: each step linearises the return mapping with
its consistent tangent and enforces zero gap on the current contact set A,

    [ K     0   -N_A^T ] [du]   [ -r ]      K = sum_T |T| B_T^T C_alg,T B_T
    [ 0     0    1^T   ] [dU] = [  F ]      r = sum_T |T| B_T^T sigma_T
    [ -N_A  1    0     ] [lam]  [ g_A]      g = N u + psi - U

after which A is updated by the complementarity rule ``lam_i - c g_i > 0``.
Works in the O(1) units of :func:`~elastoplast.fem.discretize.nondimensionalize`,
where ``c = 1`` is the stiffness of one element.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import consistent_tangent


@dataclass(frozen=True)
class Polished:
    """Outcome of :func:`newton_polish` (arrays in the units of its input)."""

    u_free: np.ndarray
    U: float
    contact_force: np.ndarray
    steps: int
    converged: bool


def newton_polish(
    disc: Discretization,
    u_free: np.ndarray,
    U: float,
    contact_force: np.ndarray,
    *,
    max_steps: int = 12,
    rtol: float = 1e-13,
) -> Polished:
    """Primal-dual active-set Newton from ``(u, U, lam)``; see the module docstring.

    Stops when the contact set repeats and the Newton correction is below
    ``rtol`` of the displacement scale.
    """
    m = disc.material
    u, lam = u_free.astype(float).copy(), contact_force.astype(float).copy()
    active = lam - (disc.N @ u + disc.psi - U) > 0
    scale = max(abs(U), np.abs(u).max(initial=0.0), np.finfo(float).tiny)
    for step in range(1, max_steps + 1):
        if not np.any(active):
            break
        sigma, _, C_alg = consistent_tangent(m, disc.strain(u), disc.state)
        r = disc.internal_force(sigma)
        K = disc.weighted_gram(C_alg)
        NA = disc.N[active]
        na = NA.shape[0]
        ones = sp.csr_matrix(np.ones((1, na)))
        system = sp.bmat(
            [[K, None, -NA.T], [None, sp.csr_matrix((1, 1)), ones], [-NA, ones.T, None]], format="csc"
        )
        rhs = np.concatenate([-r, [disc.force], NA @ u + disc.psi[active] - U])
        try:
            sol = spla.splu(system).solve(rhs)
        except RuntimeError:  # singular: e.g. a mechanism with H = 0
            break
        du, dU, lam_a = sol[: u.size], sol[u.size], sol[u.size + 1:]
        if not np.all(np.isfinite(sol)):
            break
        u += du
        U += dU
        lam[:] = 0.0
        lam[active] = lam_a
        new_active = lam - (disc.N @ u + disc.psi - U) > 0
        small = max(np.abs(du).max(initial=0.0), abs(dU)) <= rtol * scale
        if np.array_equal(new_active, active) and small:
            return Polished(u, U, lam, step, True)
        active = new_active
    return Polished(u, U, lam, max_steps, False)
