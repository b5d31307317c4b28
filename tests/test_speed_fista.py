"""FISTA's work arrays (issue 18) against the expressions they replace: the loop of
``uzawa-fast`` as it was written, with fresh temporaries, gives the same iterates to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import build, sphere_quarter_dict
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.solvers.accelerated import RHO_SHARE, FastOptions, solve_uzawa_fast, strain_inner
from elastoplast.solvers.contact import metric_projection
from elastoplast.solvers.uzawa import project_stresses


def reference_fista(disc, iterations: int, factorization: str):
    """The FISTA loop with the expressions of before (no certificate, a fixed number of iterations)."""
    nd, units = nondimensionalize(disc)
    rho = RHO_SHARE / nd.material.max_stiffness_eigenvalue()
    proj = metric_projection(nd, units.length, np.eye(nd.k), factorization, None, 1e-2)
    zero = np.zeros(nd.n_free)
    x, X, lam = proj(zero, 0.0, zero, 0.0, nd.force, nd.N, nd.psi)
    x_old, X_old, t = x.copy(), X, 1.0
    e_x = nd.strain(x)
    e_old = e_x
    restarts = 0
    for _ in range(iterations):
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        beta = (t - 1.0) / t_new
        y, Y = x + beta * (x - x_old), X + beta * (X - X_old)
        e_y = e_x + beta * (e_x - e_old)
        s_y, _ = project_stresses(nd.material, e_y, nd.state)
        x_new, X_new, lam = proj(y, Y, nd.internal_force(s_y), rho, nd.force, nd.N, nd.psi, lam)
        e_new = nd.strain(x_new)
        if strain_inner(nd, e_y - e_new, e_new - e_x, Y - X_new, X_new - X, proj.weight) > 0.0:
            t_new = 1.0
            restarts += 1
        x_old, X_old, x, X, t = x, X, x_new, X_new, t_new
        e_old, e_x = e_x, e_new
    return x, X, restarts


@pytest.mark.parametrize("factorization", ["splu", "amg"])
def test_fista_with_work_arrays_gives_the_same_iterates(factorization):
    disc = build(sphere_quarter_dict((5, 5, 4), hardening=2000.0))
    n = 30
    sol = solve_uzawa_fast(disc, FastOptions(max_iter=n, check_every=n, tol=1e-13, factorization=factorization))
    assert sol.iterations == n
    x, X, restarts = reference_fista(disc, n, factorization)
    _, units = nondimensionalize(disc)
    assert restarts > 0 and f"{restarts} restarts" in sol.message
    assert np.array_equal(disc.free_displacement(sol.u), x * units.displacement)
    assert sol.U == X * units.displacement
