"""The constitutive law: return mapping R (docs/certificate.md) and its tangent."""

from __future__ import annotations

import numpy as np
import pytest

from elastoplast.fem.material import (Material, consistent_tangent, deviator, return_mapping, von_mises)

MAT = Material(E=200e3, nu=0.3, yield_stress=250.0, hardening=2e3)


def strains(dim: int, n: int = 50, seed: int = 0) -> np.ndarray:
    """Random strains from a tenth to a few yield strains: elastic and plastic mixed."""
    k = 4 if dim == 2 else 6
    rng = np.random.default_rng(seed)
    eps = rng.normal(size=(n, k)) * rng.uniform(0.1, 4.0, size=(n, 1)) * MAT.yield_stress / MAT.E
    if dim == 2:
        eps[:, 2] = 0.0  # plane strain
    return eps


@pytest.mark.parametrize("dim", [2, 3])
def test_return_mapping_lands_on_the_hardened_yield_surface(dim):
    eps = strains(dim)
    sigma, xi, dk = return_mapping(MAT, eps)
    plastic = dk > 0
    assert plastic.any() and (~plastic).any()
    # plastic: on the yield surface sqrt(3/2)|dev sigma| = sigma_y + xi, xi = H dkappa
    assert np.allclose(von_mises(sigma[plastic]), MAT.yield_stress + xi[plastic], rtol=1e-12)
    assert np.allclose(xi, MAT.hardening * dk)
    # elastic: Hooke's law; everywhere the pressure is untouched (deviatoric flow)
    C = MAT.stiffness(dim)
    assert np.allclose(sigma[~plastic], eps[~plastic] @ C)
    assert np.allclose(sigma[:, :3].sum(1), (eps @ C)[:, :3].sum(1))
    # the flow is radial: dev sigma parallel to the trial deviator
    s, s_tr = deviator(sigma), deviator(eps @ C)
    cos = np.einsum("ij,ij->i", s, s_tr) / np.linalg.norm(s, axis=1) / np.linalg.norm(s_tr, axis=1)
    assert np.allclose(cos, 1.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_return_mapping_is_the_energy_projection(dim):
    """R is the projection of (C eps, 0) onto D in the [.,.] metric: for every
    admissible (tau, eta), [(C eps, 0) - R, (tau, eta) - R] <= 0."""
    eps = strains(dim, n=20, seed=1)
    sigma, xi, _ = return_mapping(MAT, eps)
    A = MAT.compliance(dim)
    rng = np.random.default_rng(2)
    for _ in range(200):
        tau = rng.normal(size=eps.shape) * 2 * MAT.yield_stress
        eta = np.maximum(von_mises(tau) - MAT.yield_stress, 0.0) + rng.uniform(0, 50, size=len(eps))
        lhs = np.einsum("ij,jk,ik->i", eps @ MAT.stiffness(dim) - sigma, A, tau - sigma) + (0 - xi) * (eta - xi) / MAT.hardening
        assert np.all(lhs <= 1e-9 * MAT.yield_stress**2 / MAT.E)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("H", [2e3, 0.0])
def test_consistent_tangent_matches_finite_differences(dim, H):
    mat = Material(MAT.E, MAT.nu, MAT.yield_stress, H)
    eps = strains(dim, n=30, seed=3)
    _, _, tangent = consistent_tangent(mat, eps)
    h = 1e-7 * np.abs(eps).max()
    k = eps.shape[1]
    for j in range(k):
        if dim == 2 and j == 2:
            continue  # eps33 = 0 in plane strain
        e = np.zeros(k)
        e[j] = h
        fd = (return_mapping(mat, eps + e)[0] - return_mapping(mat, eps - e)[0]) / (2 * h)
        # central differences: O(h^2) truncation, relative to the stiffness E
        assert np.allclose(tangent[:, :, j], fd, atol=1e-6 * mat.E)
