"""The KKT certificate accepts the solution and rejects perturbed ones.

Negative controls: each perturbation is a few percent of the quantity it
touches and must raise the matching residual above 1e-3.
"""

from __future__ import annotations

import numpy as np

from elastoplast.certificate.kkt import certify, contact_forces


def test_solution_passes(cylinder_disc, cylinder_conic):
    s = cylinder_conic
    assert certify(cylinder_disc, s.sigma, s.xi, s.u, s.U).worst < 1e-6


def test_perturbed_U_is_caught(cylinder_disc, cylinder_conic):
    s = cylinder_conic
    up = certify(cylinder_disc, s.sigma, s.xi, s.u, 1.01 * s.U)  # B pushed into the body
    assert up.penetration > 1e-3
    down = certify(cylinder_disc, s.sigma, s.xi, s.u, 0.99 * s.U)  # gaps open under load
    assert down.complementarity > 1e-3


def test_perturbed_element_stress_is_caught(cylinder_disc, cylinder_conic):
    s = cylinder_conic
    sigma = s.sigma.copy()
    worst = np.argmax(np.linalg.norm(sigma, axis=1))
    sigma[worst] *= 1.05
    res = certify(cylinder_disc, sigma, s.xi, s.u, s.U)
    assert res.constitutive_max > 1e-3  # the matching residual: this element's law
    # the global residuals see it too, diluted over the 1600 elements
    assert res.constitutive > 1e3 * s.kkt.constitutive
    assert res.equilibrium > 1e3 * s.kkt.equilibrium


def test_perturbed_contact_force_is_caught(cylinder_disc, cylinder_conic):
    s = cylinder_conic
    lam = contact_forces(cylinder_disc, s.sigma)
    lam[np.argmax(lam)] *= 1.05
    res = certify(cylinder_disc, s.sigma, s.xi, s.u, s.U, contact_force=lam)
    assert res.equilibrium > 1e-3
    assert res.force_balance > 1e-3


def test_nonzero_fixed_displacement_is_caught(cylinder_disc, cylinder_conic):
    s = cylinder_conic
    u = s.u.copy().ravel()
    u[cylinder_disc.fixed[0]] = 0.05 * s.U
    assert certify(cylinder_disc, s.sigma, s.xi, u, s.U).dirichlet > 1e-3
