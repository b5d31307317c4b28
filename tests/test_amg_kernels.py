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
from conftest import ROOT, build, sphere_quarter_dict
from elastoplast.certificate.kkt import certify, propagated, propagated_at_contact
from elastoplast.fem.assembly import assemble
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.linalg.amg import AMG, FaceSystems, add_in_place, changed_blocks, contact_dofs
from elastoplast.linalg.blocks import (block_layout, block_rows, block_transpose, bsr, constrain, constrain_again,
                                      near_null_space)


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


@pytest.mark.parametrize("change", ["face", "tangent"])
def test_refresh_adds_the_coarse_changes_in_place_as_scipy_sums(quarter, change):
    """The refreshed coarse operators (their changes added into their own blocks) equal
    scipy's ``coarse + R delta P`` entry by entry, for a new face and for new values."""
    import scipy.sparse as sp

    _, nd, lay, data = quarter
    rng = np.random.default_rng(5)
    A0 = bsr(lay, constrain(lay, data, ~lay.free))
    fixed = ~lay.free
    if change == "face":
        fixed[nd.free[contact_dofs(nd)[rng.random(nd.n_contact) < 0.5]]] = True
        A1 = bsr(lay, constrain(lay, data, fixed))
    else:  # a few elements' blocks scaled, as a tangent's plastic elements change them
        new = data.copy()
        new[rng.random(len(new)) < 0.05] *= 0.5
        A1 = bsr(lay, constrain(lay, 0.5 * (new + new[block_transpose(lay)].swapaxes(1, 2)), fixed))
    amg = AMG(A0, near_null_space(lay), max_coarse=10)
    levels = amg.hierarchy.levels
    assert len(levels) >= 3
    expected, delta = [], changed_blocks(A0, A1)
    for fine, coarse in zip(levels[:-1], levels[1:]):
        delta = fine.R @ (delta @ fine.P)
        expected.append((coarse.A + delta).toarray())
    # the same hierarchy refreshed by scipy's sums (the path taken when a change leaves the pattern)
    other = AMG(A0, near_null_space(lay), max_coarse=10)
    r = rng.standard_normal(A0.shape[0])
    assert any(hasattr(level.A, "block_D_inv") for level in levels[1:])  # pyamg's caches of A0's values
    amg.refresh(A1)
    import elastoplast.linalg.amg as amg_module
    kept, amg_module.add_in_place = amg_module.add_in_place, lambda A, delta: False
    try:
        other.refresh(A1)
    finally:
        amg_module.add_in_place = kept
    for level, want in zip(levels[1:], expected):
        assert np.array_equal(level.A.toarray(), want)
    # the same V-cycle to rounding (no stale cache of A0's values; scipy's sums order the blocks
    # of a row otherwise, so the smoother adds in another order)
    x, y = amg.apply(r), other.apply(r)
    assert np.allclose(x, y, rtol=0.0, atol=1e-13 * np.abs(y).max())
    # a change outside the pattern is refused and leaves the matrix as it was
    A = levels[1].A
    before = A.toarray()
    outside = sp.bsr_matrix(np.ones(A.shape)).tobsr(blocksize=A.blocksize)
    if outside.nnz > A.nnz:
        assert not add_in_place(A, outside)
        assert np.array_equal(A.toarray(), before)



def test_bordered_elimination_on_first_use_equals_the_eager_one(quarter):
    """``z = M b`` and ``s`` of the bordered preconditioner, formed at the first
    preconditioning, are those formed with the system (and a system never
    preconditioned forms neither)."""
    from elastoplast.linalg.amg import BorderedSystem

    _, _, lay, data = quarter
    A = bsr(lay, constrain(lay, data, ~lay.free))
    amg = AMG(A, near_null_space(lay), max_coarse=50)
    rng = np.random.default_rng(4)
    b = np.where(lay.free, rng.standard_normal(A.shape[0]), 0.0)
    c = float(b @ b) + 1.0
    system = BorderedSystem(A, amg, b, c)
    assert system._z is None
    r = rng.standard_normal(A.shape[0] + 1)
    z = amg.apply(b)
    s = c - float(b @ z)
    s = s if s > 1e-3 * c else 0.5 * c
    t = (r[-1] - z @ r[:-1]) / s
    assert np.array_equal(system.precondition(r), np.append(amg.apply(r[:-1]) - z * t, t))
    assert np.array_equal(system.z, z) and system.s == s


def test_constrain_again_equals_constrain_of_the_new_face(quarter):
    """A face array rewritten for another face (the kept array of two faces ago) holds,
    to the bit, what constrain gives for that face, over a sequence of faces."""
    _, nd, lay, data = quarter
    T = block_transpose(lay)
    rng = np.random.default_rng(6)
    crows = nd.free[contact_dofs(nd)]
    was = ~lay.free
    out = constrain(lay, data, was, T)
    for share in (0.5, 0.2, 0.9, 0.0, 0.5):
        fixed = ~lay.free
        fixed[crows[rng.random(crows.size) < share]] = True
        fixed[rng.random(fixed.size) < 0.02] = True
        out = constrain_again(lay, data, out, was, fixed, T)
        assert np.array_equal(out, constrain(lay, data, fixed, T))
        was = fixed


def test_face_systems_keep_two_face_arrays(quarter):
    """Faces solved in turn give what a fresh FaceSystems gives for each (the rewritten
    array is never one in use)."""
    _, nd, lay, _ = quarter
    cd = contact_dofs(nd)
    data = assemble(lay, np.eye(nd.k))
    rng = np.random.default_rng(8)
    kept = FaceSystems(lay, nd.free, cd, data, weight=1.0)
    for _ in range(5):
        fixed = np.zeros(nd.n_free + 1, dtype=bool)
        fixed[cd[rng.random(cd.size) < 0.5]] = True
        rhs = rng.standard_normal(nd.n_free + 1)
        x, _ = kept.solve(fixed, rhs, 1e-12)
        fresh = FaceSystems(lay, nd.free, cd, data, weight=1.0)
        y, _ = fresh.solve(fixed, rhs, 1e-12)
        assert np.allclose(x, y, rtol=0.0, atol=1e-9 * np.abs(y).max())
        fixed_dofs = ~lay.free
        fixed_dofs[nd.free[fixed[:-1]]] = True
        assert np.array_equal(kept._cached[2].A.data, constrain(lay, data, fixed_dofs))
    assert len(kept._faces) == 2 and kept.setups == 1


def test_kept_columns_carried_to_a_new_face_equal_their_products(quarter):
    """The kept columns' ``H V`` carried from the last face to the next (contact rows
    fixed or freed) equal the products by the new face's system, to rounding; and the
    solves that use them reach their tolerance."""
    _, nd, lay, _ = quarter
    cd = contact_dofs(nd)
    faces = FaceSystems(lay, nd.free, cd, assemble(lay, np.eye(nd.k)), weight=0.5, recycle=8)
    rng = np.random.default_rng(9)
    fixed = np.zeros(nd.n_free + 1, dtype=bool)
    carried = []
    carry = faces._carry_over

    def counted(*args):
        valid = carry(*args)
        carried.append(len(valid))
        return valid

    faces._carry_over = counted
    for step in range(12):
        if step % 2 == 0:  # a new face: some contact rows fixed, some freed
            flip = cd[rng.random(cd.size) < 0.2]
            fixed[flip] = ~fixed[flip]
        rhs = rng.standard_normal(nd.n_free + 1)
        _, info = faces.solve(fixed, rhs, 1e-10)
        assert info["cg_residual"] <= 1e-10
        system = faces._for
        for j in faces._valid:
            want = system.matvec(faces._V[:, j])
            assert np.allclose(faces._HV[:, j], want, rtol=0.0, atol=1e-12 * np.abs(want).max())
    assert sum(c > 0 for c in carried) >= 4  # new faces that carried kept columns over


def test_axisymmetric_near_null_space_holds_the_meridian_rigid_motions():
    """In the meridian plane the coarse levels must hold radial displacements too: with the
    axial translation alone (the body's only rigid motion) pyamg warned "less target
    vectors than blocksize" and CG needed 1000 iterations at 10k triangles."""
    import warnings

    from elastoplast.linalg.amg import BorderedSystem, pcg

    data = ep.read_toml(ROOT / "problems" / "sphere_axisymmetric.toml")
    data["mesh"]["divisions"] = [48, 48]
    disc = ep.discretize(ep.problem_from_dict(data))
    nd, units = nondimensionalize(disc)
    lay = block_layout(nd, units.length)
    B = near_null_space(lay)
    assert B.shape == (lay.n_dofs, 3)
    A = bsr(lay, constrain(lay, assemble(lay, nd.material.stiffness(nd.dim)), ~lay.free))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        amg = AMG(A, B, max_coarse=50)
    system = BorderedSystem(A, amg)
    f = lay.embed(nd.N.T @ np.ones(nd.n_contact), nd.free)
    _, its, ok = pcg(system.matvec, system.precondition, f, None, 1e-10, 200)
    assert ok and its <= 60, its


def test_axisymmetric_newton_on_the_amg_path_warns_nothing():
    import warnings

    data = ep.read_toml(ROOT / "problems" / "sphere_axisymmetric.toml")
    data["mesh"]["divisions"] = [24, 24]
    disc = ep.discretize(ep.problem_from_dict(data))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        amg = ep.solve(disc, "newton", linear_solver="amg", tol=1e-8, progress=False)
    direct = ep.solve(disc, "newton", linear_solver="auto", tol=1e-8, progress=False)
    assert amg.converged and direct.converged
    assert abs(amg.U - direct.U) <= 1e-6 * abs(direct.U)
