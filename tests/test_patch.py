"""Homogeneous patch test: a block on a flat punch covering its whole bottom.

The sides carry zero normal displacement and the top zero vertical displacement,
so the exact state is uniaxial strain along x_d, which P1/P0 represent exactly on
any mesh. Closed form (derived from docs/math.md): with axial strain
``e = -U / h`` (h the block height), ``M = lam + 2 mu`` and the axial stress
``F / A`` in magnitude (A the bottom area, per unit thickness in 2D),

* elastic while ``F/A <= M sigma_y / (2 mu)``: ``|e| = (F/A) / M``;
* beyond, the plastic strain is ``p diag(-1/2, -1/2, 1)`` (axis last) with
  equivalent plastic strain ``kappa = |p| = (2 mu |e| - sigma_y) / (3 mu + H)``
  and ``F/A = M |e| - 2 mu kappa``, hence
  ``|e| = (F/A - 2 mu sigma_y / (3 mu + H)) / (M - 4 mu^2 / (3 mu + H))``,
  and ``xi = H kappa``.
"""

from __future__ import annotations

import numpy as np
import pytest

import elastoplast as ep

E, NU, SY, H = 200e3, 0.3, 250.0, 20e3


def uniaxial_strain(F_over_A: float, m: ep.Material) -> tuple[float, float]:
    """``(|e|, kappa)`` of the closed form above."""
    M = m.lam + 2 * m.mu
    if F_over_A <= M * m.yield_stress / (2 * m.mu):
        return F_over_A / M, 0.0
    c = 3 * m.mu + m.hardening
    e = (F_over_A - 2 * m.mu * m.yield_stress / c) / (M - 4 * m.mu**2 / c)
    return e, (2 * m.mu * e - m.yield_stress) / c


def patch_problem(dim: int, F: float) -> ep.Problem:
    if dim == 2:
        mesh = {"generator": "rectangle", "size": [3.0, 2.0], "divisions": [6, 5]}
        fix = {"x": ["xmin", "xmax"], "y": ["top"]}
    else:
        mesh = {"generator": "box", "size": [3.0, 2.0, 2.0], "divisions": [4, 3, 3]}
        fix = {"x": ["xmin", "xmax"], "y": ["ymin", "ymax"], "z": ["top"]}
    mesh.update(grading=1.7, contact_radius=10.0)  # graded, and Γ0 covers the whole bottom
    return ep.problem_from_dict({
        "mesh": mesh,
        "material": {"E": E, "nu": NU, "yield_stress": SY, "hardening": H},
        "boundary": {"clamped": [], "contact": ["bottom"], "fix_component": fix},
        "obstacle": {"shape": "flat"},
        "load": {"force": F},
    })


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("stress_ratio", [0.5, 3.0], ids=["elastic", "plastic"])
@pytest.mark.parametrize("method", ["conic", "conic-displacement"])
def test_uniaxial_strain_is_exact(dim, stress_ratio, method):
    m = ep.Material(E, NU, SY, H)
    A = 3.0 if dim == 2 else 6.0
    first_yield = (m.lam + 2 * m.mu) * SY / (2 * m.mu)  # axial stress at first yield
    F = stress_ratio * first_yield * A
    disc = ep.discretize(patch_problem(dim, F))
    sol = ep.solve(disc, method)
    assert sol.converged, sol.message
    e, kappa = uniaxial_strain(F / A, m)
    height = 2.0
    assert sol.U == pytest.approx(e * height, rel=1e-6)
    # every element carries the same stress: axial F/A, hardening H kappa
    assert np.allclose(sol.sigma[:, dim - 1], -F / A, rtol=1e-6)
    assert np.allclose(sol.xi, H * kappa, rtol=1e-6, atol=1e-9 * SY)
    assert np.all(sol.plastic) == (stress_ratio > 1) and np.any(sol.plastic) == (stress_ratio > 1)
    assert sol.kkt.worst < 1e-6
