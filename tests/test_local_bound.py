"""The local lower bound (elastoplast/bounds/local/construction.py): an exactly admissible field built from
the P1 solution, certified by the same static certificate as the global program.

Where the numbers come from:
* the lift's dimensions: balanced linear face tractions on a simplex number
  (d+1) d^2 (d values per facet vertex) less d + d(d-1)/2 balance conditions: 9 in 2D, 30 in 3D;
* patch tests: the uniaxial-strain closed form Pi* (tests/test_equilibrium.py). A uniform
  discrete stress is reproduced exactly (its tractions are the averaged ones and balance every
  star), so the local bound is Pi* to round-off;
* weak duality: every certified lower bound is at most every upper bound. The local field
  lives on the barycentric split (a richer space than the global program's linear stress
  per element), so it is *not* bounded by the global optimum of the same mesh; with 2 sweeps
  on 576 triangles it is below it (measured: benchmarks/bounds/local.md has the local
  bound above the optimum after 12 sweeps at 576 and 1,600 triangles, both certified);
* sweeps only accept steps that lower J, so J never increases with more sweeps, and the
  extra sweeps on the hot stars only lower it further; the plane-strain tau33 (no
  equilibrium row) is moved only where it lowers an element's J;
* the contact layer's correction is the least norm (sum |T| |Delta_T|^2) over its elements,
  so a deeper layer (a superset) never needs a larger one;
* negative controls: a perturbed field and a field built from unbalanced forces are refused;
* the lift on a thin element: the tractions of a constant stress, balanced to round-off, come
  back on the facets to 1e-13 at condition number ~120 (2D; 2e-13 in 3D). Measured (3 seeds):
  2e-14 and 6e-14 with the refined lift, up to 2.0e-13 and 3.5e-13 with the reference lift
  alone, whose least squares in the reference metric amplifies the input's round-off
  imbalance (up to 2e-12 traction jumps on the cylinder at 25,600 triangles).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import build, cylinder_dict, sphere_quarter_dict
from test_equilibrium import closed_form_energy, patch_force
from test_patch import E, H, NU, SY, patch_problem

import elastoplast as ep
from elastoplast.bounds.local import construction, contact
from elastoplast.bounds.local.lift import element_maps, lift, reference_lift
from elastoplast.bounds.local.construction import equilibrated_field, local_lower_bound
from elastoplast.bounds.equilibrium.bound import solve_lower_bound
from elastoplast.bounds.static import certify_static, mass_matrix
from elastoplast.references.solves import best_upper_bound
from elastoplast.errors import InputError
from elastoplast.fem.material import von_mises


@pytest.mark.parametrize("dim, count", [(2, 9), (3, 30)])
def test_composite_element_lifts_every_balanced_traction(dim, count):
    ref = reference_lift(dim)
    assert ref.balanced_dim == count
    assert ref.homogeneous_dim == count  # divergence-free, traction-continuous stresses on the split
    assert ref.traction_rank == count  # ... map onto the balanced tractions: one-to-one


@pytest.mark.parametrize("dim, tol", [(2, 1e-13), (3, 2e-13)])
def test_lift_of_a_thin_element_returns_its_facet_tractions(dim, tol):
    d1 = dim + 1
    off = (1.0 - np.eye(d1))[None, :, :, None]
    for seed in range(3):
        rng = np.random.default_rng(seed)
        X = np.array([[0, 0], [1, 0], [0.37, 0.01]]) if dim == 2 else \
            np.array([[0, 0, 0], [1, 0, 0], [0.4, 0.01, 0], [0.3, 0.002, 0.01]])
        Q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
        maps = element_maps(3.7 * X @ Q.T + rng.normal(size=dim), np.arange(d1)[None])
        assert np.linalg.cond(maps.J[0]) > 100
        g = np.concatenate([-maps.Jinv.sum(axis=1, keepdims=True), maps.Jinv], axis=1)
        n = -g / np.linalg.norm(g, axis=2, keepdims=True)  # outward unit normals
        S = rng.normal(size=(dim, dim))
        t = np.einsum("jk,nik->nij", S + S.T, n)[:, :, None, :] * off  # a constant stress's tractions
        sig = lift(maps, t)
        back = np.einsum("niajk,nik->niaj", sig, n) * off
        assert np.abs(back - t).max() <= tol * np.abs(t).max()


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("stress_ratio", [0.5, 3.0], ids=["elastic", "plastic"])
def test_patch_local_bound_is_the_closed_form(dim, stress_ratio):
    m = ep.Material(E, NU, SY, H)
    F = patch_force(dim, stress_ratio, m)
    disc = ep.discretize(patch_problem(dim, F))
    sol = ep.solve(disc, "newton")
    lb = local_lower_bound(disc, sol, n_sweeps=2)  # the ring sweeps keep a closed-form field (no step lowers J)
    _, Pi = closed_form_energy(dim, F, m)
    assert lb.certified, lb.message
    assert lb.lower <= Pi + 1e-12 * abs(Pi)
    assert Pi - lb.lower <= 1e-10 * abs(Pi)


@pytest.fixture(scope="module")
def cylinder():
    disc = build(cylinder_dict(divisions=(24, 12)))
    sol = ep.solve(disc, "newton")
    return disc, sol, best_upper_bound(disc, sol, method="newton")


def test_local_bound_is_certified_below_the_upper_and_the_global_optimum(cylinder):
    disc, sol, up = cylinder
    lb = local_lower_bound(disc, sol, n_sweeps=2, descent=0)  # the sweeps alone (the descent passes the optimum)
    assert lb.certified, lb.message
    assert np.any(von_mises(lb.field.tau.reshape(-1, disc.k)) > disc.material.yield_stress)  # plastic
    assert np.all(lb.field.lam >= 0)
    assert lb.local.facet_force.sum() == pytest.approx(disc.force, rel=1e-13)
    assert up.certified
    assert lb.lower <= up.Pi
    glob = solve_lower_bound(disc)
    assert glob.certified
    assert lb.lower <= glob.lower  # measured at 2 sweeps, not a theorem (module docstring)
    from elastoplast.bounds.bracket import combine

    b = combine(up, lb)
    assert b.bounds_certified
    # the local gap terms sum to the gap (an exactly admissible field)
    assert b.element_gap.sum() + b.facet_gap.sum() == pytest.approx(b.energy_gap, rel=1e-8)


def test_sweeps_never_increase_J(cylinder):
    disc, sol, _ = cylinder
    J = {s: local_lower_bound(disc, sol, n_sweeps=s, descent=0).J for s in (0, 1, 2, 4)}
    # each sweep only accepts ring steps that lower J (the repair moves J by round-off only)
    assert J[1] <= J[0] and J[2] <= J[1] * (1 - 1e-12) and J[4] <= J[2] * (1 - 1e-12)


def test_tau33_moves_only_towards_lower_J(cylinder):
    disc, sol, _ = cylinder
    lf = equilibrated_field(disc, sol.sigma, sol.contact_force)
    sd = lf.split.disc
    tau = lf.field.tau.copy()
    tau[..., 2] = disc.material.nu * (tau[..., 0] + tau[..., 1])  # the elastic minimiser, not J's
    new = construction.optimal_tau33(sd, tau)
    assert np.array_equal(new[..., [0, 1, 3]], tau[..., [0, 1, 3]])  # equilibrium untouched
    e0, e1 = construction.element_energies(sd, tau[:, None]), construction.element_energies(sd, new[:, None])
    assert np.all(e1 <= e0 * (1 + 1e-12))  # kept only where it lowers J (to round-off: two summation orders)
    assert e1.sum() < e0.sum()  # the field is plastic (previous test): tau33 matters


def test_deeper_contact_layer_needs_a_smaller_correction(cylinder, monkeypatch):
    # least norm (sum |T| |Delta_T|^2) over a superset of elements is never larger
    disc, sol, _ = cylinder
    from elastoplast.bounds.local.equilibrate import mesh_faces
    from elastoplast.bounds.local.lift import element_maps

    maps = element_maps(disc.mesh.points, disc.mesh.cells)
    faces = mesh_faces(disc.mesh.cells, disc.facet_topology, maps.facet_areas)
    S = construction.in_plane_stress(disc, sol.sigma)
    norms = []
    for depth in (0.0, contact.LAYER_DEPTH):
        monkeypatch.setattr(contact, "LAYER_DEPTH", depth)
        _, dS = contact.contact_pressure_and_correction(disc, faces, S, sol.contact_force)
        norms.append(float(np.einsum("e,eij,eij->", disc.volumes, dS, dS)))
    assert norms[1] <= norms[0] * (1 + 1e-12)


def test_the_pressure_carries_the_contact_forces_resultant_and_moments_exactly(cylinder):
    """The layer next to Γ0 is a free body: its correction can only carry a mismatch of zero
    net force and moment, so the fitted pressure's resultant and first moment are
    constraints of the fit. Contact forces skewed by ``1 + x / 2w`` (w the zone's half
    width; any non-negative forces summing to F are valid input) make the moment nonzero:
    the earlier fit, with those rows weighted by 1e3, left a moment mismatch of 2.4e-8 of
    F w here (5e-10 at 6,400 triangles), which no layer can carry."""
    disc, sol, _ = cylinder
    from elastoplast.bounds.local.equilibrate import mesh_faces
    from elastoplast.bounds.local.lift import element_maps
    from elastoplast.bounds.static import mass_matrix

    maps = element_maps(disc.mesh.points, disc.mesh.cells)
    faces = mesh_faces(disc.mesh.cells, disc.facet_topology, maps.facet_areas)
    cf = faces.n_interior + disc.facet_topology.contact_index
    fn, measure = faces.nodes[cf], faces.measure[cf]
    x = disc.mesh.points[disc.contact_nodes, 0]
    r = np.asarray(sol.contact_force) * (1 + 0.5 * x / np.abs(x).max())
    r *= disc.force / r.sum()
    lam = contact.nodal_pressure(disc, fn, measure, r)
    assert np.all(lam >= 0)
    moments = np.zeros(disc.mesh.n_nodes)  # int phi_a lam per node
    np.add.at(moments, fn.ravel(), (measure[:, None] * (lam[fn] @ mass_matrix(disc.dim - 1))).ravel())
    assert moments.sum() == pytest.approx(disc.force, rel=1e-14)
    assert abs(moments[disc.contact_nodes] @ x - r @ x) <= 1e-14 * disc.force * np.abs(x).max()
    assert abs(r @ x) > 1e-3 * disc.force * np.abs(x).max()  # the skew moved the moment off zero


def test_a_layer_too_thin_for_an_exact_correction_grows(cylinder, monkeypatch):
    """An adaptively refined 3D default problem (19,780 tetrahedra) left a relative residual
    of 1.3e-11 with the three-ring layer and round-off with four: the layer grows ring by ring
    (at most LAYER_GROWTH) until its correction is exact, else the refusal names the rings
    tried. Here the thinner layers are made to fail."""
    disc, sol, _ = cylinder
    from elastoplast.bounds.local.equilibrate import mesh_faces
    from elastoplast.bounds.local.lift import element_maps

    maps = element_maps(disc.mesh.points, disc.mesh.cells)
    faces = mesh_faces(disc.mesh.cells, disc.facet_topology, maps.facet_areas)
    S = construction.in_plane_stress(disc, sol.sigma)
    exact = contact.layer_correction
    tried = []

    def thin_fails(disc, on_contact, measure, delta, r, rings, fail_below):
        tried.append(rings)
        dS, worst = exact(disc, on_contact, measure, delta, r, rings)
        return dS, (1e-9 if rings < fail_below else worst)

    start = contact.LAYER_RINGS
    monkeypatch.setattr(contact, "layer_correction", lambda *a: thin_fails(*a, fail_below=start + 2))
    _, dS = contact.contact_pressure_and_correction(disc, faces, S, sol.contact_force)
    assert tried == [start, start + 1, start + 2]
    monkeypatch.setattr(contact, "layer_correction", exact)
    _, direct = contact.contact_pressure_and_correction(disc, faces, S, sol.contact_force, start + 2)
    assert np.array_equal(dS, direct)  # the grown layer's own correction
    tried.clear()
    monkeypatch.setattr(contact, "layer_correction", lambda *a: thin_fails(*a, fail_below=99))
    with pytest.raises(ep.InputError, match=f"layers of {start} to {start + contact.LAYER_GROWTH} rings"):
        contact.contact_pressure_and_correction(disc, faces, S, sol.contact_force)
    assert tried == list(range(start, start + contact.LAYER_GROWTH + 1))


def test_3d_local_bound_is_certified():
    disc = build(sphere_quarter_dict(divisions=(3, 3, 3)))
    sol = ep.solve(disc, "newton")
    lb = local_lower_bound(disc, sol, n_sweeps=0)
    assert lb.certified, lb.message
    assert lb.lower <= best_upper_bound(disc, sol, method="newton").Pi


def test_perturbed_and_unbalanced_fields_are_refused(cylinder):
    disc, sol, _ = cylinder
    lf = equilibrated_field(disc, sol.sigma, sol.contact_force)
    tau = lf.field.tau.copy()
    tau[0, 0, 0] += 1e-6 * np.abs(tau).max()
    from dataclasses import replace

    cert = certify_static(lf.split.disc, replace(lf.field, tau=tau))
    assert not cert.passed and "equilibrium" in cert.failed
    # a dropped balance: stresses out of nodal balance (one element's stress changed)
    sigma = sol.sigma.copy()
    sigma[disc.n_elements // 2] *= 1.01
    bad = equilibrated_field(disc, sigma, sol.contact_force)
    assert bad.star_residual > 1e-6
    assert not certify_static(bad.split.disc, bad.field).passed


def test_no_local_bound_without_hardening(cylinder):
    from dataclasses import replace

    disc, sol, _ = cylinder
    perfect = replace(disc, problem=replace(disc.problem, material=replace(disc.material, hardening=0.0)))
    with pytest.raises(InputError, match="H > 0"):
        local_lower_bound(perfect, sol)


def test_plastic_energy_is_never_under_estimated():
    """eta linear on a simplex with vertex values max(0, vm - sigma_y) is >= max(0, vm(tau) - sigma_y)
    everywhere (convexity), so its exactly integrated square bounds the plastic energy: checked
    against a fine quadrature (midpoints of a 40-fold refinement, positive weights) of both."""
    rng = np.random.default_rng(1)
    sy = 1.0
    n = 40
    # barycentric lattice midpoints of a regular refinement of the triangle (equal weights)
    pts = []
    for i in range(n):
        for j in range(n - i):
            pts.append(((i + 1 / 3) / n, (j + 1 / 3) / n))
            if i + j < n - 1:
                pts.append(((i + 2 / 3) / n, (j + 2 / 3) / n))
    P = np.array(pts)
    bary = np.column_stack([1 - P.sum(1), P])
    for _ in range(20):
        tau = rng.normal(size=(3, 4)) * 2.0
        eta_v = np.maximum(von_mises(tau) - sy, 0.0)
        tau_x = bary @ tau
        g = np.maximum(von_mises(tau_x) - sy, 0.0)
        eta_x = bary @ eta_v
        assert np.all(eta_x >= g - 1e-12)
        exact = eta_v @ mass_matrix(2) @ eta_v  # int eta^2 / |T|
        assert exact >= np.mean(g ** 2) - 1e-12


def _noisy_sweep(size):
    """A stand-in for the sweeps that adds round-off-like noise (``size`` relative to max |t|,
    on the interior facets' components): the accumulated round-off the repair removes."""
    from elastoplast.bounds.local import sweeps

    real = sweeps.ring_sweep

    def noisy(points, cells, maps, faces, rings, t, *args, **kw):
        out = real(points, cells, maps, faces, rings, t, *args, **kw)
        noise = np.random.default_rng(0).standard_normal(out.shape) * size * np.abs(out).max()
        noise[faces.n_interior:] = 0.0
        return out + noise

    return noisy


def test_round_off_repair_restores_the_certificate(cylinder, monkeypatch):
    """Random noise of 5e-12 relative in the tractions (5 times the certificate's 1e-12; the
    sweeps' own round-off measured 2-3e-12 at 6,400 triangles before the repair) is refused
    without the repair, certified with it, and the repaired bound equals the clean one to
    that relative size (the repair moves the field by the size of the noise)."""
    from elastoplast.bounds.local import sweeps

    disc, sol, _ = cylinder
    clean = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    monkeypatch.setattr(sweeps, "ring_sweep", _noisy_sweep(5e-12))
    repaired = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    assert repaired.certified, repaired.message
    assert "whole-mesh" not in repaired.message  # ring passes only: nothing global factored
    assert repaired.lower == pytest.approx(clean.lower, rel=1e-9)
    monkeypatch.setattr(sweeps, "ring_repair", lambda p, c, m, f, t, b, free, tol, passes: (t, 0.0, 0.0))
    unrepaired = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    assert not unrepaired.certified and "traction_jump" in unrepaired.certificate.failed


def test_swept_field_certifies_where_the_round_off_was_refused():
    """6,400 triangles and 6 sweeps: the traction residual reached 2.2e-12 before the repair
    (refused at 1e-12); now certified and below the upper bound."""
    disc = build(cylinder_dict(divisions=(80, 40)))
    sol = ep.solve(disc, "newton")
    lb = local_lower_bound(disc, sol, n_sweeps=6)
    assert lb.certified, lb.message
    # a perturbation of the repaired field is still refused
    tau = lb.field.tau.copy()
    tau[7, 1, 0] += 1e-9 * np.abs(tau).max()
    from dataclasses import replace

    from elastoplast.bounds.local.construction import split_discretization

    assert not certify_static(split_discretization(disc).disc, replace(lb.field, tau=tau)).passed


def test_the_load_is_restored_after_the_sweeps(cylinder, monkeypatch):
    """The pressure after the sweeps scaled by 1 + 1e-11 (the descent's held pressures once
    left int lam 2e-12 of F off on an adapted cylinder mesh, refused at 1e-12): certified with
    the load restored, int lam = F to round-off and the bound the clean one to that relative
    size; refused for force_balance without the restoration."""
    from elastoplast.bounds.local import sweeps

    disc, sol, _ = cylinder
    clean = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    sweep = sweeps.ring_sweep

    def drifted(points, cells, maps, faces, *args):
        t = sweep(points, cells, maps, faces, *args)
        cf = faces.n_interior + disc.facet_topology.contact_index
        t[cf, :, disc.dim - 1] *= 1 + 1e-11
        return t

    monkeypatch.setattr(sweeps, "ring_sweep", drifted)
    restored = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    assert restored.certified, restored.message
    assert restored.certificate.force_balance <= 1e-14
    assert restored.lower == pytest.approx(clean.lower, rel=1e-9)
    monkeypatch.setattr(construction, "restore_load", lambda t, measure, cf, F: None)
    drifting = local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    assert not drifting.certified and drifting.certificate.failed == ("force_balance",)
