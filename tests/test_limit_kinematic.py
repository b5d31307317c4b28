"""The kinematic upper bound on the limit load (docs/bounds.md, H = 0).

Where the asserted numbers come from:

* plane-strain compression between smooth platens: the homogeneous velocity
  ``v = (x / h, 1 - y / h)`` is P1, trace-free and lifts the bottom by 1; it
  dissipates ``2k |ε11| = 2k / h`` per unit area, ``2k w`` over a w x h block, and
  the uniform stress ``σ22 = -2k`` (``σ33 = -k``) is admissible and carries the
  same load: ``F_c = 2k w`` exactly (in 3D, uniaxial ``F_c = σ_y A``);
* Prandtl's punch (docs/validation.md): ``F_c = (2 + π) k b`` for a half model of a
  punch of half-width b on a block that contains the mechanism (Prandtl's field
  fits in 3b x 1.5b; the clamped sides can only add strength);
* nested spaces: refining the crossed pattern by halving, and P1 inside P2, can
  only lower the optimum;
* the column of uniaxial stress ``σ_zz = -σ_y`` above a flat punch, running to the
  clamped top, is admissible: ``F_c >= σ_y |Γ0|``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.bounds.limit_load import LimitOptions, dissipation, kinematic_limit_load, limit_load, velocity_space

SY = 250.0
K = SY / np.sqrt(3.0)


def make(mesh: ep.Mesh, clamped=(), fix=None, contact=("contact",), hardening=0.0) -> ep.Discretization:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # perfect plasticity warning
        return ep.discretize(ep.Problem(mesh=mesh, material=ep.Material(200e3, 0.3, SY, hardening),
                                        boundary=ep.Boundary(clamped=tuple(clamped), contact=tuple(contact),
                                                             fix_component=fix or {}),
                                        obstacle=ep.Obstacle("flat", mesh.dim, center=(0.0,) * (mesh.dim - 1)),
                                        force=1.0))


def contact_measure(disc: ep.Discretization) -> float:
    cf = np.concatenate([disc.mesh.groups[n] for n in disc.problem.boundary.contact])
    X = disc.mesh.points[cf][:, :, :-1]
    if disc.dim == 2:
        return float(np.abs(X[:, 1, 0] - X[:, 0, 0]).sum())
    u, v = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]
    return float(0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum())


def half_punch(n: int, grading: float = 1.0, b: float = 1.0) -> ep.Discretization:
    """Half model (symmetry x = 0) of a punch of half-width b on a 4b x 2b block,
    crossed pattern, n squares per b, graded toward the punch edge (a node)."""
    mesh = ep.structured_mesh([4 * b, 2 * b], [4 * n, 2 * n], contact_radius=b, origin=[0.0, 0.0],
                              contact_center=[b], grading=grading, pattern="crossed")
    groups = dict(mesh.groups)
    bottom = groups["bottom"]
    groups["contact"] = bottom[np.all(mesh.points[bottom][:, :, 0] <= b * (1 + 1e-12), axis=1)]
    mesh = ep.Mesh(points=mesh.points, cells=mesh.cells, groups=groups)
    return make(mesh, clamped=("xmax", "top"), fix={0: ("xmin",)})


def test_plane_strain_dissipation_is_the_support_function_of_von_mises():
    rng = np.random.default_rng(0)
    e11, e12 = rng.normal(size=(2, 200))
    eps = np.stack([e11, -e11, 0 * e11, np.sqrt(2) * e12], axis=1)  # Mandel, tr = 0, eps33 = 0
    D = dissipation(SY, eps)
    np.testing.assert_allclose(D, 2 * K * np.sqrt(e11**2 + e12**2), rtol=1e-14)
    # the 3D formula on the same tensor written in 3D Mandel notation
    eps3 = np.stack([e11, -e11, 0 * e11, 0 * e11, 0 * e11, np.sqrt(2) * e12], axis=1)
    np.testing.assert_allclose(dissipation(SY, eps3), D, rtol=1e-14)
    # sup over von Mises-admissible stresses: attained at sigma* = sqrt(2/3) sigma_y eps/|eps|
    star = np.sqrt(2 / 3) * SY * eps / np.linalg.norm(eps, axis=1, keepdims=True)
    np.testing.assert_allclose(ep.von_mises(star), SY, rtol=1e-14)
    np.testing.assert_allclose(np.einsum("ei,ei->e", star, eps), D, rtol=1e-14)
    sig = rng.normal(size=(200, 4)) * SY
    sig *= np.minimum(1.0, SY / ep.von_mises(sig))[:, None]  # any admissible stress, sigma33 free
    assert np.all(np.einsum("ei,ei->e", sig, eps) <= D * (1 + 1e-12))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [1, 2])
def test_compression_between_smooth_platens_is_exact(dim, order):
    if dim == 2:
        mesh = ep.structured_mesh([1.5, 2.0], [3, 4], contact_radius=10.0, origin=[0.0, 0.0], grading=1.5)
        fix, exact = {0: ("xmin",), 1: ("top",)}, 2 * K * 1.5
    else:
        mesh = ep.structured_mesh([1.5, 1.0, 2.0], [2, 2, 3], contact_radius=10.0, origin=[0.0, 0.0, 0.0], grading=1.5)
        fix, exact = {0: ("xmin",), 1: ("ymin",), 2: ("top",)}, SY * 1.5
    disc = make(mesh, fix=fix, contact=("bottom",))
    r = kinematic_limit_load(disc, LimitOptions(order=order))
    assert r.certified, r.message
    assert r.F_upper == pytest.approx(exact, rel=1e-7)
    assert r.F_upper >= exact * (1 - 1e-12)  # an upper bound: never below F_c beyond round-off
    assert r.trace_residual < 1e-12


def test_prandtl_upper_bounds_are_above_prandtl_and_decrease_on_nested_spaces():
    prandtl = (2 + np.pi) * K  # b = 1, half model
    coarse, fine = half_punch(2), half_punch(4)
    up = {(n, o): kinematic_limit_load(d, LimitOptions(order=o)).F_upper
          for n, d in ((2, coarse), (4, fine)) for o in (1, 2)}
    for val in up.values():
        assert val >= prandtl
    assert up[4, 1] <= up[2, 1] * (1 + 1e-7)  # crossed mesh 4 refines crossed mesh 2
    assert up[2, 2] <= up[2, 1] * (1 + 1e-7)  # P1 inside P2
    assert up[4, 2] <= up[4, 1] * (1 + 1e-7)
    assert up[4, 2] <= up[2, 2] * (1 + 1e-7)


def test_prandtl_bracket_on_a_graded_crossed_punch():
    disc = half_punch(4, grading=2.0)
    assert contact_measure(disc) == pytest.approx(1.0)
    prandtl = (2 + np.pi) * K
    res = limit_load(disc)
    assert res.certified, res.message
    assert res.F_lower <= prandtl <= res.F_upper
    assert res.ratio == pytest.approx(res.F_upper / res.F_lower)


def test_diagonal_p1_locks_and_p2_does_not():
    mesh = ep.structured_mesh([4.0, 2.0], [8, 4], contact_radius=1.0, origin=[0.0, 0.0])
    disc = make(mesh, clamped=("xmax", "top"), fix={0: ("xmin",)})
    p1 = kinematic_limit_load(disc, LimitOptions(order=1))
    assert p1.F_upper == np.inf and not p1.certified and "locks" in p1.message
    p2 = kinematic_limit_load(disc, LimitOptions(order=2))
    assert p2.certified and np.isfinite(p2.F_upper) and p2.F_upper >= (2 + np.pi) * K


def test_3d_flat_punch_bound_lies_above_the_static_column():
    mesh = ep.structured_mesh([2.0, 2.0, 1.5], [4, 4, 3], contact_radius=1.0, origin=[0.0, 0.0, 0.0])
    disc = make(mesh, clamped=("xmax", "ymax", "top"), fix={0: ("xmin",), 1: ("ymin",)})
    res = limit_load(disc)
    assert res.upper.certified and res.upper.order == 2
    assert res.F_upper >= SY * contact_measure(disc)
    p1 = kinematic_limit_load(disc, LimitOptions(order=1))
    assert p1.F_upper >= res.F_upper  # P1 inside P2 (P1 tetrahedra lock: here infinite)
    assert res.certified, res.message
    assert res.F_lower <= res.F_upper


@pytest.mark.parametrize("order", [1, 2])
def test_clarabel_assembly_matches_a_cvxpy_model(order):
    import cvxpy as cp

    disc = half_punch(2)
    space = velocity_space(disc, order)
    v = cp.Variable(space.n_free)
    eps = cp.reshape(space.B @ v, (space.n_points, space.k), order="C")
    obj = SY * np.sqrt(2 / 3) * cp.sum(cp.multiply(space.weights, cp.norm(eps, 2, axis=1)))
    prob = cp.Problem(cp.Minimize(obj), [eps[:, 0] + eps[:, 1] + eps[:, 2] == 0, space.contact @ v >= 1])
    prob.solve(solver=cp.CLARABEL)
    r = kinematic_limit_load(disc, LimitOptions(order=order))
    assert r.F_upper == pytest.approx(prob.value, rel=1e-6)
    assert r.solver_value == pytest.approx(prob.value, rel=1e-6)


def test_hardening_is_refused():
    mesh = ep.structured_mesh([4.0, 2.0], [4, 2], contact_radius=1.0)
    disc = make(mesh, clamped=("xmin", "xmax", "top"), hardening=1000.0)
    for fn in (limit_load, kinematic_limit_load):
        with pytest.raises(ep.InputError) as exc:
            fn(disc)
        assert exc.value.field == "material.hardening"


def test_no_contact_nodes_and_bad_order_are_input_errors():
    with pytest.raises(ep.InputError) as exc:
        ep.discretize(ep.problem_from_dict({
            "mesh": {"generator": "rectangle", "size": [4.0, 2.0], "divisions": [4, 2], "contact_radius": 0.1},
            "material": {"E": 1e3, "nu": 0.3, "yield_stress": 1.0, "hardening": 1.0},
            "obstacle": {"shape": "flat"}, "load": {"force": 1.0}}))
    assert exc.value.field == "mesh.contact_radius"  # no bottom facet lies within 0.1 of the centre
    with pytest.raises(ep.InputError) as exc:
        kinematic_limit_load(half_punch(1), LimitOptions(order=3))
    assert exc.value.field == "order"


def test_curved_obstacle_says_the_load_is_not_physical():
    mesh = ep.structured_mesh([4.0, 2.0], [8, 4], contact_radius=1.0, pattern="crossed")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = ep.discretize(ep.Problem(mesh=mesh, material=ep.Material(1e3, 0.3, SY, 0.0),
                                        boundary=ep.Boundary(("xmin", "xmax", "top"), ("contact",)),
                                        obstacle=ep.Obstacle("cylinder", 2, radius=5.0, center=(0.0,)), force=1.0))
    r = kinematic_limit_load(disc, LimitOptions(order=1))
    assert "not a physical limit load" in r.message


def test_kinematic_program_is_dimensionless():
    """The program is solved with the mean element size as unit length: scaling the
    mesh by s scales the 2D bound by s (a force per unit length: sigma_y * length)."""
    vals = []
    for s in (1.0, 1e-3):
        mesh = ep.structured_mesh([4 * s, 2 * s], [8, 4], contact_radius=s, origin=[0.0, 0.0], pattern="crossed")
        disc = make(mesh, clamped=("xmax", "top"), fix={0: ("xmin",)})
        vals.append(kinematic_limit_load(disc, LimitOptions(order=1)).F_upper / s)
    assert vals[1] == pytest.approx(vals[0], rel=1e-6)
