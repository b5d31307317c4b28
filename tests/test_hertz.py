"""Hertz contact of a cylinder in plane strain, elastic limit (docs/validation.md).

b = sqrt(4 F R / (pi E*)), p0 = 2 F / (pi b), E* = E / (1 - nu^2). The block has
half-width 20 b and height 20 b, so it is large against the contact; clamping
its sides and top stiffens it slightly against a half-space.
"""

from __future__ import annotations

import numpy as np
import pytest

import elastoplast as ep

E, NU, R, B = 200e3, 0.3, 40.0, 1.0
E_STAR = E / (1 - NU**2)
F = np.pi * E_STAR * B**2 / (4 * R)  # chosen so that the Hertz half-width is B
P0 = 2 * F / (np.pi * B)


@pytest.fixture(scope="module")
def hertz():
    problem = ep.problem_from_dict({
        # graded toward the contact: spacing about 0.15 b at the contact edge
        "mesh": {"generator": "rectangle", "size": [40 * B, 20 * B], "divisions": [120, 60],
                 "grading": 2.0, "contact_radius": 3 * B},
        # a yield stress far above any stress here: the elastic limit
        "material": {"E": E, "nu": NU, "yield_stress": 1e12, "hardening": E / 10},
        "obstacle": {"shape": "cylinder", "radius": R},
        "load": {"force": F},
    })
    disc = ep.discretize(problem)
    return disc, ep.solve(disc, "conic")


def test_half_width_and_peak_pressure_match_hertz(hertz):
    disc, sol = hertz
    assert sol.converged and sol.kkt.worst < 1e-6
    s = ep.summary(disc, sol)
    # the issue asks for 5% on a refined mesh of a large block
    assert s["contact_radius"] == pytest.approx(B, rel=0.05)
    assert s["max_contact_pressure"] == pytest.approx(P0, rel=0.05)
    assert not sol.plastic.any()


def test_pressure_profile_is_elliptic(hertz):
    """Away from the edge the nodal pressures follow p0 sqrt(1 - x^2/b^2)."""
    disc, sol = hertz
    x = disc.mesh.points[disc.contact_nodes, 0]
    inner = np.abs(x) < 0.7 * B
    hertz_p = P0 * np.sqrt(1 - (x[inner] / B) ** 2)
    # 5% of p0, the same bound the issue sets for the peak
    assert np.max(np.abs(sol.contact_pressure[inner] - hertz_p)) < 0.05 * P0
    # symmetric mesh and load: the pressure is even in x to solver precision
    order = np.argsort(x)
    assert np.allclose(sol.contact_force[order], sol.contact_force[order][::-1], rtol=1e-6, atol=1e-9 * F)
