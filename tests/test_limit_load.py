"""Perfect plasticity: a rigid flat punch in plane strain has a limit load.

Prandtl's limit pressure is (2 + pi) k with k = sigma_y / sqrt 3 (docs/validation.md,
"Prandtl's flat punch"). The discrete limit load of (2.1) approaches it from above as the
mesh is refined: benchmarks/validation measured limit/Prandtl = 1.088 and 1.044
at spacings w/4 and w/8 under the punch (w its width). Here the spacing under
the punch is about w/6, so 0.9 Prandtl must be carried and 1.2 Prandtl must not.
Only the crossed pattern is used: two triangles per square lock under plastic
incompressibility and carry far more (measured: still solved at 3 Prandtl).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import elastoplast as ep

SIGMA_Y, HALF_WIDTH = 250.0, 1.0
PRANDTL_FORCE = (2 + np.pi) * SIGMA_Y / np.sqrt(3) * 2 * HALF_WIDTH


def punch(pattern: str) -> ep.Discretization:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the perfect-plasticity warning
        return ep.discretize(ep.problem_from_dict({
            "mesh": {"generator": "rectangle", "size": [20.0, 10.0], "divisions": [20, 10], "grading": 1.5,
                     "contact_radius": HALF_WIDTH, "pattern": pattern},
            "material": {"E": 200e3, "nu": 0.3, "yield_stress": SIGMA_Y, "hardening": 0.0},
            "obstacle": {"shape": "flat"},
            "load": {"force": 1.0},
        }))


@pytest.mark.parametrize("ratio,expected", [(0.9, ep.Status.CONVERGED), (1.2, ep.Status.INFEASIBLE)])
def test_flat_punch_limit_load_brackets_prandtl(ratio, expected):
    disc = punch("crossed")
    sol = ep.solve(disc.with_force(ratio * PRANDTL_FORCE), "conic")
    assert sol.status is expected, sol.message
    if expected is ep.Status.CONVERGED:
        assert sol.kkt.worst < 1e-6
        assert sol.plastic.any()
    else:
        assert "limit load" in sol.message


def test_crossed_pattern_is_a_conforming_symmetric_mesh():
    disc = punch("crossed")
    mesh = disc.mesh
    assert mesh.n_elements == 4 * 20 * 10
    assert disc.volumes.sum() == pytest.approx(200.0)  # the rectangle's area
    # mirror symmetry about x = 0: every node has its image
    pts = {tuple(np.round(p, 12)) for p in mesh.points}
    assert all((round(-x, 12) + 0.0, y) in pts for x, y in pts)
