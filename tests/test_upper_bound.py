"""The certified upper bound Pi(v, V) >= Pi* and the energy / U brackets (docs/bounds.md).

Where the numbers come from:
* W(ε) = ∫_0^1 R(tε):ε dt because dW/dε = R(ε); R(tε):ε is affine in t on each
  side of the yield onset, so two Gauss points per side integrate it exactly;
* Fenchel-Young: W(ε) >= τ:ε - 1/2 Aτ:τ - η²/2H on D, with equality at R(ε);
* value_D of (D) is ∫ W(ε(u)) - F U (elastoplast.certificate.solution);
* the facet rule is exact for the paraboloid at a right triangle's hypotenuse
  midpoint (the centre of its smallest enclosing ball): ψ - I_hψ = -r²/(2R) there;
  for the cylinder ψ'' lies between 1/R and k, so the true dip of a facet lies
  between k_min r²/2 and the bound k r²/2;
* the patch test (uniaxial strain, tests/test_patch.py): the exact continuum
  solution is P1 and its stress uniform, so both bounds are the closed form and the
  U bracket contains the closed-form U;
* weak duality: the local gap terms sum to upper - lower and are each >= 0.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import build, cylinder_dict, sphere_quarter_dict
from test_equilibrium import closed_form_energy
from test_patch import E, H, NU, SY, patch_problem, uniaxial_strain

import elastoplast as ep
from elastoplast.bounds.upper import EXPRESSION_PIECES, conservative_discretization, enclosing_radius, hencky_energy_density, penetration_bound, smallest_upper_bound, upper_bound
from elastoplast.references.solves import best_upper_bound
from elastoplast.references.certified import bounds_at, energy_bounds
from elastoplast.bounds.bracket import choose_delta, combine, u_bracket
from elastoplast.references.solves import displacement_slope
from elastoplast.bounds.equilibrium.bound import solve_lower_bound
from elastoplast.certificate.solution import value_displacement_form


def random_strains(k: int, n: int = 60, seed: int = 0) -> np.ndarray:
    eps = np.random.default_rng(seed).normal(size=(n, k)) * 4e-3
    if k == 4:
        eps[:, 2] = 0.0  # plane strain
    return eps


@pytest.mark.parametrize("k", [4, 6])
@pytest.mark.parametrize("hardening", [H, 0.0])
def test_hencky_energy_is_the_integral_of_the_return_mapping(k, hardening):
    m = ep.Material(E, NU, SY, hardening)
    eps = random_strains(k)
    dim = 2 if k == 4 else 3
    q = ep.von_mises(eps @ m.stiffness(dim))  # trial von Mises stress at t = 1
    onset = np.clip(SY / q, 0.0, 1.0)  # yield starts at t = onset
    g, w = np.polynomial.legendre.leggauss(2)
    total = np.zeros(len(eps))
    for a, b in ((np.zeros_like(onset), onset), (onset, np.ones_like(onset))):
        for gi, wi in zip(g, w):
            t = a + (b - a) * (gi + 1) / 2
            sig = ep.return_mapping(m, t[:, None] * eps)[0]
            total += wi * (b - a) / 2 * np.einsum("ei,ei->e", sig, eps)
    assert np.any(onset < 1)  # some strains are plastic
    np.testing.assert_allclose(hencky_energy_density(m, eps), total, rtol=1e-12)


def test_hencky_energy_is_the_fenchel_young_maximum():
    m = ep.Material(E, NU, SY, H)
    eps = random_strains(6, seed=1)
    W = hencky_energy_density(m, eps)
    A = m.compliance(3)
    sig, xi, _ = ep.return_mapping(m, eps)
    at_R = np.einsum("ei,ei->e", sig, eps) - 0.5 * np.einsum("ei,ij,ej->e", sig, A, sig) - 0.5 * xi**2 / H
    np.testing.assert_allclose(W, at_R, rtol=1e-12)
    rng = np.random.default_rng(2)
    for _ in range(5):
        tau = sig + rng.normal(size=sig.shape) * SY * 0.3
        eta = np.maximum(ep.von_mises(tau) - SY, 0.0) * rng.uniform(1.0, 2.0, size=len(tau))  # admissible
        val = np.einsum("ei,ei->e", tau, eps) - 0.5 * np.einsum("ei,ij,ej->e", tau, A, tau) - 0.5 * eta**2 / H
        assert np.all(val <= W + 1e-12 * np.abs(W))


def test_hencky_energy_gives_the_value_of_the_displacement_form(cylinder_disc, cylinder_conic):
    u_free = cylinder_disc.free_displacement(cylinder_conic.u)
    total = float(cylinder_disc.volumes @ hencky_energy_density(cylinder_disc.material, cylinder_disc.strain(u_free)))
    assert total - cylinder_disc.force * cylinder_conic.U == pytest.approx(
        value_displacement_form(cylinder_disc, u_free, cylinder_conic.U), rel=1e-12)


def touching(disc: ep.Discretization, U: float = 0.3) -> np.ndarray:
    """Nodal displacements with zero gap at every contact node (the worst case between nodes)."""
    u = np.zeros((disc.mesh.n_nodes, disc.dim))
    u[disc.contact_nodes, -1] = U - disc.psi
    return u


def sampled_min_gap(disc: ep.Discretization, u: np.ndarray, U: float, facets: np.ndarray, n: int = 40) -> np.ndarray:
    """The gap on a barycentric grid of each facet (the exact ψ, the linear v_d)."""
    d = disc.dim
    if d == 2:
        t = np.linspace(0, 1, n + 1)
        bary = np.stack([1 - t, t], axis=1)
    else:
        ij = np.array([(i, j) for i in range(n + 1) for j in range(n + 1 - i)]) / n
        bary = np.stack([1 - ij.sum(axis=1), ij[:, 0], ij[:, 1]], axis=1)
    X = np.einsum("sa,fac->fsc", bary, disc.mesh.points[facets][:, :, :-1])
    vd = np.einsum("sa,fa->fs", bary, u[facets, -1])
    psi = disc.problem.obstacle.psi(X.reshape(-1, d - 1)).reshape(X.shape[:2])
    return (vd + psi - U).min(axis=1)


def cylinder_problem(obstacle: dict, divisions=(20, 10)) -> ep.Discretization:
    data = cylinder_dict(divisions=divisions)
    data["obstacle"] = obstacle
    return build(data)


def test_facet_rule_for_the_cylinder_lies_between_the_curvature_bounds():
    disc = cylinder_problem({"shape": "cylinder", "radius": 5.0})
    U = 0.3
    u = touching(disc, U)
    pen = penetration_bound(disc, u, U)
    assert pen.certified
    true = sampled_min_gap(disc, u, U, pen.facets, n=400)
    assert np.all(pen.facet_gap <= true + 1e-14)
    r = enclosing_radius(disc.mesh.points[pen.facets][:, :, :-1])
    assert np.all(-true >= (1 / 5.0) * r**2 / 2 * (1 - 1e-4))  # psi'' >= 1/R: the dip is at least this
    max_pen, facet_gap = pen
    assert max_pen == pytest.approx(-facet_gap.min())


def test_facet_rule_is_exact_for_the_paraboloid_on_right_triangles():
    disc = build(sphere_quarter_dict(divisions=(4, 4, 3)) | {"obstacle": {"shape": "paraboloid", "radius": 7.0}})
    U = 0.1
    u = touching(disc, U)
    pen = penetration_bound(disc, u, U)
    X = disc.mesh.points[pen.facets][:, :, :-1]
    # the structured box splits squares into right triangles: the ball's centre is the hypotenuse midpoint
    e2 = np.stack([np.sum((X[:, (i + 1) % 3] - X[:, (i + 2) % 3]) ** 2, axis=1) for i in range(3)], axis=1)
    assert np.allclose(2 * e2.max(axis=1), e2.sum(axis=1))
    hyp = e2.argmax(axis=1)
    mid = 0.5 * (X[np.arange(len(X)), (hyp + 1) % 3] + X[np.arange(len(X)), (hyp + 2) % 3])
    psi = disc.problem.obstacle.psi
    ends = 0.5 * (psi(X[np.arange(len(X)), (hyp + 1) % 3]) + psi(X[np.arange(len(X)), (hyp + 2) % 3]))
    exact_dip = ends - psi(mid)  # I_h psi - psi at the midpoint, where the nodal gaps are zero
    np.testing.assert_allclose(-pen.facet_gap, exact_dip, rtol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_expression_obstacle_bound_is_safe_and_close(dim):
    R = 5.0
    if dim == 2:
        disc = cylinder_problem({"shape": "expression", "expression": f"x**2 / (2 * {R})"})
    else:
        disc = build(sphere_quarter_dict(divisions=(4, 4, 3)) | {"obstacle": {"shape": "expression",
                                                                              "expression": f"(x**2 + y**2) / (2 * {R})"}})
    U = 0.2
    u = touching(disc, U)
    pen = penetration_bound(disc, u, U)
    assert pen.certified, pen.method
    true = sampled_min_gap(disc, u, U, pen.facets, n=60 if dim == 3 else 400)
    assert np.all(pen.facet_gap <= true + 1e-14)
    # first order in the piece size s: the bound is within (|psi'| + |v_d'|) s of the truth
    X = disc.mesh.points[pen.facets][:, :, :-1]
    diam = np.abs(X.max(axis=1) - X.min(axis=1)).sum(axis=1)
    slope = np.linalg.norm(X, axis=2).max(axis=1) / R
    s = diam / EXPRESSION_PIECES[dim]
    assert np.all(pen.facet_gap >= true - 2 * slope * s - 1e-14)
    # the same shape as a paraboloid: the curvature rule, and both bounds are safe
    para = penetration_bound(replace_obstacle(disc, ep.Obstacle("paraboloid", dim, radius=R,
                                                                   center=(0.0,) * (dim - 1))), u, U)
    assert np.all(para.facet_gap <= true + 1e-14)


def replace_obstacle(disc: ep.Discretization, obstacle: ep.Obstacle) -> ep.Discretization:
    from dataclasses import replace

    return replace(disc, problem=replace(disc.problem, obstacle=obstacle))


def test_expression_that_cannot_be_enclosed_is_not_certified():
    disc = cylinder_problem({"shape": "expression", "expression": "0.001 / abs(x - 0.013)"})  # no node at x = 0.013
    ub = upper_bound(disc, (touching(disc), 0.3))
    assert not ub.certified
    assert "division" in ub.message


@pytest.mark.parametrize("dim", [2, 3])
def test_patch_test_bounds_are_exact(dim):
    m = ep.Material(E, NU, SY, H)
    area = 3.0 if dim == 2 else 6.0
    F = 3.0 * (m.lam + 2 * m.mu) * SY / (2 * m.mu) * area  # plastic
    disc = ep.discretize(patch_problem(dim, F))
    J, Pi = closed_form_energy(dim, F, m)
    b = energy_bounds(disc)
    assert b.bounds_certified
    assert b.energy_upper == pytest.approx(Pi, rel=1e-9)
    assert b.energy_lower == pytest.approx(Pi, rel=1e-9)
    assert b.energy_gap_rel < 1e-8


def test_u_bracket_contains_the_closed_form_u_of_the_patch_test():
    m = ep.Material(E, NU, SY, H)
    F = 3.0 * (m.lam + 2 * m.mu) * SY / (2 * m.mu) * 3.0
    disc = ep.discretize(patch_problem(2, F))
    e, _ = uniaxial_strain(F / 3.0, m)
    U = e * 2.0  # height 2
    lo, hi = u_bracket(disc, 0.1 * F, bounds_at(disc))
    assert lo <= U <= hi
    # Pi* is smooth here: the width is about U'(F) delta (the gaps vanish)
    dU = (uniaxial_strain(1.01 * F / 3.0, m)[0] - uniaxial_strain(0.99 * F / 3.0, m)[0]) * 2.0 / (0.02 * F)
    assert hi - lo == pytest.approx(dU * 0.1 * F, rel=0.05)


@pytest.fixture(scope="module")
def small_cases():
    out = {}
    for name, disc in (("2d", build(cylinder_dict(divisions=(20, 10)))),
                       ("3d", build(sphere_quarter_dict(divisions=(3, 3, 3))))):
        sol = ep.solve(disc, "conic")
        out[name] = (disc, upper_bound(disc, sol), solve_lower_bound(disc), sol)
    return out


@pytest.mark.parametrize("case", ["2d", "3d"])
def test_local_gap_terms_sum_to_the_gap_and_are_nonnegative(small_cases, case):
    disc, upper, lower, sol = small_cases[case]
    assert upper.certified and lower.certified
    b = combine(upper, lower)
    scale = abs(b.energy_upper)
    assert b.energy_lower <= b.energy_upper
    assert b.element_gap.sum() + b.facet_gap.sum() == pytest.approx(b.energy_upper - b.energy_lower, abs=1e-12 * scale)
    assert b.element_gap.min() >= -1e-12 * scale
    assert b.facet_gap.min() >= -1e-12 * scale
    assert b.stress_error_bound == pytest.approx(np.sqrt(2 * (b.energy_upper - b.energy_lower)))
    # ||R(eps(v)) - sigma||^2 + ||tau - sigma||^2 <= 2 gap, so ||R(eps(v)) - tau|| <= 2 sqrt(gap); the
    # element means of tau (the [.,.]-orthogonal projection onto P0) are no farther from the P0 R(eps(v))
    from elastoplast.certificate.kkt import energy_norm_sq

    sig_v, xi_v, _ = ep.return_mapping(disc.material, upper.strain)
    dist2 = energy_norm_sq(disc, sig_v - lower.field.tau.mean(axis=1), xi_v - lower.field.eta.mean(axis=1))
    assert np.sqrt(dist2) <= 2 * np.sqrt(b.energy_upper - b.energy_lower)
    assert set(b.as_dict()) == {"energy_lower", "energy_upper", "energy_gap_rel", "stress_error_bound",
                                "stress_error_bound_rel", "bounds_certified"}


def test_corrections_are_admissible_and_best_is_smallest(small_cases):
    disc, _, _, sol = small_cases["2d"]
    ubs = {c: upper_bound(disc, sol, c) for c in ("shift", "lift", "best")}
    for ub in ubs.values():
        assert ub.certified
        assert ub.facet_gap.min() >= -1e-15 * abs(ub.U)  # the corrected pair is in K (to round-off in U)
        assert ub.Pi >= sol.value_D  # corrections only raise Pi above the P1 value
    assert ubs["shift"].shift == pytest.approx(ubs["shift"].penetration)
    assert ubs["best"].Pi <= min(ubs["shift"].Pi, ubs["lift"].Pi) + 1e-12 * abs(ubs["best"].Pi)
    # the conservative obstacle moves the P1 solution out of the obstacle between the nodes
    cons = ep.solve(conservative_discretization(disc), "conic")
    ub = upper_bound(disc, cons, "shift")
    assert ub.penetration <= 1e-12 * abs(cons.U)


def test_best_upper_bound_falls_back_on_the_body_at_rest(small_cases):
    """Any admissible pair bounds Pi*; the body at rest (0, 0), corrected like any
    candidate, is one: W >= 0 and V <= 0, so its Pi >= 0 (here small: the facet rule
    lifts the nodes near the cylinder's touching point by k r²/2). A poor candidate
    (the P1 solution pushed three times too far, whose energy exceeds the body at
    rest's) loses to it; the P1 solution itself (Pi < 0) wins."""
    disc, upper, _, sol = small_cases["2d"]
    assert upper.Pi < 0.0
    rest = upper_bound(disc, (np.zeros((disc.mesh.n_nodes, disc.dim)), 0.0))
    assert rest.certified and rest.Pi >= 0.0 and rest.V <= 0.0
    poor = upper_bound(disc, (3.0 * sol.u, 3.0 * sol.U))
    assert poor.certified and poor.Pi > rest.Pi
    best = best_upper_bound(disc, (3.0 * sol.u, 3.0 * sol.U), conservative=False)
    assert best.certified and best.Pi == rest.Pi and "body at rest" in best.message
    good = best_upper_bound(disc, sol, conservative=False)
    assert good.Pi == upper.Pi and "body at rest" not in good.message


def test_the_smallest_of_three_candidates_counts(small_cases):
    """smallest_upper_bound ranks the problem's solution, the conservative solution and
    the body at rest by Pi (all three certified here): with the poor candidate in
    first place, the conservative solution (a good P1 field) wins, as it would alone;
    best_upper_bound with conservative=True is the same ranking after its own solve."""
    disc, _, _, sol = small_cases["2d"]
    poor = (3.0 * sol.u, 3.0 * sol.U)
    cons = ep.solve(conservative_discretization(disc), "conic")
    alone = {name: upper_bound(disc, c) for name, c in (("poor", poor), ("cons", cons),
                                                          ("rest", (np.zeros((disc.mesh.n_nodes, 2)), 0.0)))}
    assert all(ub.certified for ub in alone.values())
    assert alone["cons"].Pi < alone["rest"].Pi < alone["poor"].Pi
    best = smallest_upper_bound(disc, poor, cons)
    assert best.Pi == alone["cons"].Pi and "conservative obstacle" in best.message
    assert best_upper_bound(disc, poor, method="conic").Pi == pytest.approx(alone["cons"].Pi, rel=1e-9)


def test_lower_bounds_never_exceed_upper_bounds_across_meshes(small_cases):
    disc_a, up_a, low_a, _ = small_cases["2d"]
    disc_b = build(cylinder_dict(divisions=(30, 15)))
    up_b = upper_bound(disc_b, ep.solve(disc_b, "conic"))
    low_b = solve_lower_bound(disc_b)
    for lo in (low_a, low_b):
        for up in (up_a, up_b):
            assert -lo.J <= up.Pi


def test_u_bracket_on_a_refinement_sequence_contains_the_finer_discrete_u():
    disc = build(cylinder_dict(divisions=(20, 10)))
    b = energy_bounds(disc)
    slope = displacement_slope(disc)
    delta = choose_delta(disc.force, b.energy_upper - b.energy_lower, slope)
    assert 0 < delta < disc.force
    lo, hi = u_bracket(disc, delta, bounds_at(disc))
    for n in (20, 40):  # 1600 and 6400 triangles
        U_h = ep.solve(build(cylinder_dict(divisions=(2 * n, n))), "conic").U
        assert lo <= U_h <= hi
    # the chosen delta narrows the bracket against a four times larger or smaller one
    for other in (4 * delta, delta / 4):
        lo2, hi2 = u_bracket(disc, min(other, 0.9 * disc.force), bounds_at(disc))
        assert hi - lo <= hi2 - lo2


def test_bad_input():
    disc = build(cylinder_dict(divisions=(20, 10)))
    with pytest.raises(ep.InputError) as exc:
        u_bracket(disc, disc.force, bounds_at(disc))
    assert exc.value.field == "delta"
    with pytest.raises(ep.InputError) as exc:
        upper_bound(disc, (np.zeros((disc.mesh.n_nodes, 2)), 0.0), correction="nope")
    assert exc.value.field == "correction"
