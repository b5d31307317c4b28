"""The quarter model with F/4 reproduces the full model.

The generated meshes are mirror-symmetric about the contact centre and the
quarter mesh is exactly a quarter of the full one, so the discrete solutions
coincide: U equal to solver precision (the issue asks for 1%).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

import elastoplast as ep

from conftest import PROBLEMS, build, sphere_quarter_dict


def test_quarter_model_reproduces_full_model():
    quarter = sphere_quarter_dict(divisions=(5, 5, 4))
    full = copy.deepcopy(quarter)
    full["mesh"].update(size=[12.0, 12.0, 6.0], divisions=[10, 10, 4])
    del full["mesh"]["origin"], full["boundary"]
    full["load"]["force"] = 4 * quarter["load"]["force"]
    dq, df = build(quarter), build(full)
    assert df.n_elements == 4 * dq.n_elements
    sq, sf = ep.solve(dq, "conic"), ep.solve(df, "conic")
    assert sq.converged and sf.converged
    assert sq.U == pytest.approx(sf.U, rel=1e-6)
    assert sq.plastic.sum() * 4 == pytest.approx(sf.plastic.sum(), abs=4)
    # total contact force of the quarter is F/4 by the force balance
    assert sq.contact_force.sum() == pytest.approx(quarter["load"]["force"], rel=1e-9)


def test_shipped_quarter_problem_is_a_quarter_of_the_default():
    q = ep.read_toml(PROBLEMS / "sphere_quarter_3d.toml")
    f = ep.read_toml(PROBLEMS / "sphere_block_3d.toml")
    assert q["load"]["force"] * 4 == f["load"]["force"]
    assert [2 * s for s in q["mesh"]["size"][:2]] == f["mesh"]["size"][:2]
    assert [2 * d for d in q["mesh"]["divisions"][:2]] == f["mesh"]["divisions"][:2]
    assert np.isclose(q["mesh"]["size"][2], f["mesh"]["size"][2])
