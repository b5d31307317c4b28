"""The shortcuts of the iterative path (issue 18) against the plain computations they replace.

Each kernel is compared with the formulation it stands for, on small meshes: the
V-cycle without pyamg's residual checks against ``aspreconditioner``, the face
constraints written into the blocks of the fixed nodes against the masks over every
block, the contact rows read from the blocks against the whole matrix converted,
the certificate's round-off threshold from the contact elements against the product
over every element, and the kept hierarchy serving every face of its matrix.
"""

from __future__ import annotations

import numpy as np
import pytest

import elastoplast as ep
from conftest import build, sphere_quarter_dict
from elastoplast.certificate.kkt import certify, propagated, propagated_at_contact
from elastoplast.fem.assembly import assemble
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.linalg.amg import AMG, FaceSystems, contact_dofs
from elastoplast.linalg.blocks import block_layout, block_rows, block_transpose, bsr, constrain, near_null_space


@pytest.fixture(scope="module")
def quarter():
    disc = build(sphere_quarter_dict((6, 6, 5), hardening=2000.0))
    nd, units = nondimensionalize(disc)
    lay = block_layout(nd, units.length)
    return disc, nd, lay, assemble(lay, nd.material.stiffness(nd.dim))


def test_block_transpose_maps_each_block_to_its_transpose(quarter):
    _, _, lay, data = quarter
    T = block_transpose(lay)
    rows = np.repeat(np.arange(lay.n_nodes), np.diff(lay.indptr))
    assert np.array_equal(rows[T], lay.indices) and np.array_equal(lay.indices[T], rows)
    assert np.allclose(data[T], np.swapaxes(data, 1, 2), rtol=0, atol=1e-12 * np.abs(data).max())


def test_constrain_on_the_fixed_blocks_equals_the_masks(quarter):
    _, nd, lay, data = quarter
    rng = np.random.default_rng(3)
    fixed = ~lay.free
    fixed[nd.free[contact_dofs(nd)[rng.random(nd.n_contact) < 0.5]]] = True
    fixed[rng.random(fixed.size) < 0.05] = True
    assert np.array_equal(constrain(lay, data, fixed), constrain(lay, data, fixed, block_transpose(lay)))


def test_contact_rows_from_blocks_equal_the_converted_matrix(quarter):
    _, nd, lay, data = quarter
    rows = nd.free[contact_dofs(nd)]
    a, b = bsr(lay, data).tocsr()[rows], block_rows(lay, data, rows)
    assert abs(a - b).max() == 0.0


def test_v_cycle_is_pyamg_preconditioner_to_the_bit(quarter):
    _, _, lay, data = quarter
    A = bsr(lay, constrain(lay, data, ~lay.free))
    amg = AMG(A, near_null_space(lay), max_coarse=50)
    assert len(amg.hierarchy.levels) >= 2
    r = np.random.default_rng(0).standard_normal(A.shape[0])
    assert np.array_equal(amg.apply(r), amg.hierarchy.aspreconditioner(cycle="V") @ r)


def test_round_off_threshold_at_the_contact_equals_the_full_product(quarter):
    _, nd, _, _ = quarter
    u = np.random.default_rng(1).standard_normal(nd.n_free)
    full = nd.N @ propagated(nd, u)
    assert np.allclose(propagated_at_contact(nd, u), full, rtol=1e-14, atol=0.0)


def test_one_hierarchy_serves_every_face_of_its_matrix(quarter):
    _, nd, lay, _ = quarter
    cd = contact_dofs(nd)
    faces = FaceSystems(lay, nd.free, cd, assemble(lay, np.eye(nd.k)), weight=1.0)
    rng = np.random.default_rng(2)
    for _ in range(4):
        fixed = np.zeros(nd.n_free + 1, dtype=bool)
        fixed[cd[rng.random(cd.size) < 0.5]] = True
        rhs = rng.standard_normal(nd.n_free + 1)
        x, info = faces.solve(fixed, rhs, 1e-10)
        assert info["cg_residual"] <= 1e-10
        assert np.all(x[fixed] == 0.0)
    assert faces.setups == 1 and faces.refreshes >= 3


def test_uzawa_on_the_iterative_path_is_certified(quarter):
    disc = quarter[0]
    a = ep.solve(disc, "uzawa", tol=1e-8, factorization="amg")
    b = ep.solve(disc, "uzawa", tol=1e-8, factorization="splu")
    assert a.converged and b.converged
    assert certify(disc, a.sigma, a.xi, a.u, a.U).worst <= 1e-8
    assert abs(a.U - b.U) <= 1e-7 * abs(b.U)
