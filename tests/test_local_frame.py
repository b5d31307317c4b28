"""The descent of the local field over all rings together (elastoplast/bounds/local/descent.py).

Where the numbers come from:
* the frame spans every self-equilibrated correction: the rank of the ring corrections
  equals the dimension of the null space of the elements' balance rows (with the
  ``int lam = F`` row), both computed here; the balance rows come from
  :func:`balance_matrices`, independently of the ring bases (a dimension count);
* ``apply`` and ``adjoint`` are transposes of each other (an identity of linear maps), and
  the held-pressure rows are columns of the adjoint;
* J's gradient against central differences of J (second-order accurate, J is C1 with a
  Lipschitz gradient; the step is 1e-4 of the field);
* the projection holds the chosen pressures to round-off of the step (a projection);
* on the quarter sphere at 162 tetrahedra the sweeps stall in the plastic zone (measured:
  gap 73.3 after 32 sweeps, 72.5 after 512, the global program 29.5), while the descent
  reaches the optimum of the field's space; the issue's target, the gap at most 1.5 times
  the global program's on the same mesh, is asserted (measured 0.96 after 100 steps:
  the composite element's space holds the program's fields, so its optimum is at least as good).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import build, cylinder_dict, sphere_quarter_dict

import elastoplast as ep
from elastoplast.bounds.local.equilibrate import mesh_faces
from elastoplast.bounds.local.descent import RingFrame, field_energy, pressure_projection
from elastoplast.bounds.local.lift import element_maps
from elastoplast.bounds.local.construction import local_lower_bound
from elastoplast.bounds.equilibrium.bound import solve_lower_bound
from elastoplast.bounds.local.rings import mesh_rings, ring_batches
from elastoplast.bounds.local.state import sweep_state
from elastoplast.bounds.static import psi_weights
from elastoplast.bounds.local.energy import balance_matrices
from elastoplast.references.solves import best_upper_bound
from elastoplast.fem.material import von_mises


def frame_of(disc):
    mesh, topo, d = disc.mesh, disc.facet_topology, disc.dim
    maps = element_maps(mesh.points, mesh.cells)
    faces = mesh_faces(mesh.cells, topo, maps.facet_areas)
    cf = faces.n_interior + topo.contact_index
    free = faces.unknown.copy()
    free[cf, d - 1] = True  # the contact pressure moves with the rings
    rings = mesh_rings(mesh.points, mesh.cells)
    batches = ring_batches(mesh.points, mesh.cells, disc.grads, faces, rings, free)
    frame = RingFrame(batches, mesh.points, faces, rings, d)
    return disc, maps, faces, cf, free, rings, frame


@pytest.fixture(scope="module")
def quarter():
    return frame_of(build(sphere_quarter_dict(divisions=(3, 3, 3))))


def balance_rows(disc, maps, faces, free, cf):
    """The elements' force and moment rows on the free traction entries, and ``int lam``."""
    mesh, d = disc.mesh, disc.dim
    C = balance_matrices(mesh.points, mesh.cells, maps.facet_areas)  # (n, nb, (d+1)(d+1)d)
    n, nb = C.shape[:2]
    nF, dd = faces.nodes.shape[0], d * d
    A = np.zeros((n * nb + 1, nF * dd))
    e, i, a = np.nonzero(faces.slot >= 0)
    for j in range(d):
        col = faces.face[e, i] * dd + faces.slot[e, i, a] * d + j
        val = faces.sign[e, i][:, None] * C[e, :, (i * (d + 1) + a) * d + j]  # (k, nb)
        np.add.at(A, (e[:, None] * nb + np.arange(nb), col[:, None]), val)
    for sl in range(d):
        A[-1, cf * dd + sl * d + d - 1] = faces.measure[cf] / d
    mask = np.repeat(free[:, None, :], d, axis=1).reshape(-1)
    return A[:, mask], mask


@pytest.mark.parametrize("data", [cylinder_dict(divisions=(8, 4)), sphere_quarter_dict(divisions=(3, 3, 2))],
                         ids=["2D", "3D"])
def test_the_ring_frame_spans_every_self_equilibrated_correction(data):
    disc, maps, faces, cf, free, rings, frame = frame_of(build(data))
    d = disc.dim
    A, mask = balance_rows(disc, maps, faces, free, cf)
    sv = np.linalg.svd(A, compute_uv=False)
    null_dim = mask.sum() - int((sv > sv[0] * 1e-10).sum())
    # rank(B) = rank(B^T W) for random W on the free entries with more columns than the rank
    rng = np.random.default_rng(0)
    W = np.zeros((null_dim + 40, mask.size))
    W[:, mask] = rng.normal(size=(null_dim + 40, mask.sum()))
    C = frame.adjoint(W.reshape(-1, faces.nodes.shape[0], d, d))
    ev = np.linalg.eigvalsh(C @ C.T)  # squares of the singular values: measured gap 1.6e-11 (2D), 4e-11 (3D) to 1e-32
    # in 2D the contact zone lies inside the free bottom edge: moving its resultant moment needs a
    # path through the body from the contact zone to the clamped sides, which no star holds;
    # on the quarter sphere the contact zone touches the symmetry planes, and nothing is missing
    missing = 1 if d == 2 else 0
    assert int((ev > ev[-1] * 1e-13).sum()) == null_dim - missing
    # and every ring correction is self-equilibrated on the free entries only
    BW = np.stack([frame.apply(rng.normal(size=frame.size)).reshape(-1) for _ in range(20)], axis=1)
    assert np.abs(BW[~mask]).max() == 0.0
    assert np.abs(A @ BW[mask]).max() <= 1e-12 * np.abs(A).max() * np.abs(BW).max() * 10


def test_apply_and_adjoint_are_transposes_and_unit_rows_are_adjoint_columns(quarter):
    disc, maps, faces, cf, free, rings, frame = quarter
    rng = np.random.default_rng(1)
    y = rng.normal(size=frame.size)
    g = rng.normal(size=(faces.nodes.shape[0], 3, 3))
    lhs, rhs = float((frame.apply(y) * g).sum()), float(y @ frame.adjoint(g))
    assert lhs == pytest.approx(rhs, rel=1e-12)
    f, x = cf[[0, 0, 1, 1]], np.array([2, 5, 8, 5])
    cols, rows = frame.unit_rows(f, x)
    E = np.zeros((4,) + g.shape)
    E.reshape(4, -1, 9)[np.arange(4), f, x] = 1.0
    full = frame.adjoint(E)
    assert np.array_equal(full[:, cols], rows.toarray())
    rest = np.ones(frame.size, dtype=bool)
    rest[cols] = False
    assert np.abs(full[:, rest]).max() == 0.0


def _state(disc, maps, faces, cf):
    """J's sweep state with the problem's obstacle weights on the Γ0 facets."""
    d = disc.dim
    psi = np.zeros((faces.nodes.shape[0], d))
    psi[cf] = psi_weights(disc, disc.facet_topology).q
    contact = np.zeros(faces.nodes.shape[0], dtype=bool)
    contact[cf] = True
    return sweep_state(disc.material, maps, faces, None, psi, contact)


def test_field_energy_gradient_matches_central_differences(quarter):
    disc, maps, faces, cf, free, rings, frame = quarter
    state = _state(disc, maps, faces, cf)
    rng = np.random.default_rng(2)
    t = rng.normal(size=(faces.nodes.shape[0], 3, 3)) * disc.material.yield_stress * 1.5  # a plastic state
    J, g = field_energy(maps, faces, t, disc.volumes, state)
    dt = frame.apply(rng.normal(size=frame.size))
    h = 1e-4 * np.abs(t).max() / np.abs(dt).max()
    Jp, _ = field_energy(maps, faces, t + h * dt, disc.volumes, state, gradient=False)
    Jm, _ = field_energy(maps, faces, t - h * dt, disc.volumes, state, gradient=False)
    assert (Jp - Jm) / (2 * h) == pytest.approx(float((g * dt).sum()), rel=1e-6)


def test_the_projection_holds_the_chosen_pressures(quarter):
    disc, maps, faces, cf, free, rings, frame = quarter
    t = np.zeros((faces.nodes.shape[0], 3, 3))
    held = np.array([[0, 0], [0, 1], [1, 2]])
    contact = np.zeros(faces.nodes.shape[0], dtype=bool)
    contact[cf] = True
    proj = pressure_projection(frame, t, held, contact)
    rng = np.random.default_rng(3)
    dt = frame.apply(proj(rng.normal(size=frame.size)))
    moved = dt[cf[held[:, 0]], held[:, 1], 2]
    assert np.abs(moved).max() <= 1e-13 * np.abs(dt[cf, :, 2]).max()
    assert np.abs(dt[cf, :, 2]).max() > 0  # the other pressures still move


def test_the_descent_reaches_the_program_where_the_sweeps_stall(quarter):
    disc = quarter[0]
    sol = ep.solve(disc, "newton")
    up = best_upper_bound(disc, sol, method="newton")
    swept = local_lower_bound(disc, sol, 8, descent=0)
    lb = local_lower_bound(disc, sol, 8, descent=300)
    glob = solve_lower_bound(disc)
    assert lb.certified and swept.certified and glob.certified and up.certified
    assert lb.J <= swept.J  # the descent only takes steps that lower J
    assert np.all(lb.field.lam >= 0)
    assert lb.lower <= up.Pi
    assert up.Pi - lb.lower <= 1.5 * (up.Pi - glob.lower)
    assert up.Pi - swept.lower > 2.0 * (up.Pi - glob.lower)  # the stall this descent exists for


def test_the_descent_stops_early_when_its_gains_are_small_against_the_gap(quarter):
    """With an upper bound far above (a huge gap) every window of steps gains little against
    it, so the descent stops after DESCENT_WINDOW steps; without one, or with an infinite one
    (no gap to compare with), it runs on."""
    from elastoplast.bounds.local.descent import DESCENT_WINDOW

    disc = quarter[0]
    sol = ep.solve(disc, "newton")
    free_run = local_lower_bound(disc, sol, 8, descent=60)
    far = local_lower_bound(disc, sol, 8, descent=60, upper=1e12)
    endless = local_lower_bound(disc, sol, 8, descent=60, upper=float("inf"))
    assert far.timings["descent_steps"] == DESCENT_WINDOW
    assert free_run.timings["descent_steps"] > DESCENT_WINDOW
    assert endless.timings["descent_steps"] == free_run.timings["descent_steps"] and endless.J == free_run.J
    assert far.certified and far.J >= free_run.J


def test_the_pressures_held_in_one_step_are_held_from_the_start_of_the_next(quarter, monkeypatch):
    """Every projection holds only pressures at zero (at most ZERO_PRESSURE of the largest:
    holding a positive one would be a needless restriction), some step starts with the pairs
    the last one held (the carried set: a step with nothing carried calls no projection
    before its first direction), and the set is found afresh every HOLD_STEPS steps."""
    import elastoplast.bounds.local.descent as fr

    disc = quarter[0]
    sol = ep.solve(disc, "newton")
    calls = []
    project, fresh = fr.pressure_projection, fr.still_zero

    def spy(frame, t, held, contact):
        lam = t[np.flatnonzero(contact), :, 2]
        calls.append(("hold", held.copy(), lam[held[:, 0], held[:, 1]].max(), lam.max()))
        return project(frame, t, held, contact)

    def carried(t, pairs, contact):
        kept = fresh(t, pairs, contact)
        calls.append(("carry", kept.copy()))
        return kept

    monkeypatch.setattr(fr, "pressure_projection", spy)
    monkeypatch.setattr(fr, "still_zero", carried)
    lb = local_lower_bound(disc, sol, 8, descent=2 * fr.HOLD_STEPS + 1)
    steps = lb.timings["descent_steps"]
    assert lb.certified and steps == 2 * fr.HOLD_STEPS + 1
    holds = [c for c in calls if c[0] == "hold"]
    assert holds and all(top <= fr.ZERO_PRESSURE * largest for _, _, top, largest in holds)
    carries = [c[1] for c in calls if c[0] == "carry"]
    assert len(carries) == steps - 3  # steps 0, HOLD_STEPS and 2 HOLD_STEPS start afresh
    assert any(c.size for c in carries)


def test_field_energy_is_the_sum_of_the_element_energies(quarter):
    """The compiled J of the descent against the batched numpy pieces of the sweeps (the lift
    ``sweeps.lifted_stresses`` and ``energy.element_energy``) plus the obstacle term, at a plastic state."""
    from elastoplast.bounds.local.sweeps import lifted_stresses
    from elastoplast.bounds.local.energy import element_energy

    disc, maps, faces, cf, free, rings, frame = quarter
    state = _state(disc, maps, faces, cf)
    rng = np.random.default_rng(4)
    t = rng.normal(size=(faces.nodes.shape[0], 3, 3)) * disc.material.yield_stress * 1.5
    J, _ = field_energy(maps, faces, t, disc.volumes, state, gradient=False)
    n = disc.n_elements
    sig = lifted_stresses(maps, faces, t, np.arange(n), state.TP, state.scale, state).reshape(n, 4, 4, -1)
    el = element_energy(sig, disc.volumes / 4, state.MA, state.M, state.sy, state.H)
    assert el.max() > 0 and (von_mises(sig) > state.sy).any()
    assert J == pytest.approx(el.sum() + (state.psi[cf] * t[cf, :, 2]).sum(), rel=1e-12)


def test_the_descent_goes_on_where_held_rows_nearly_depend():
    """An adaptively refined cylinder mesh (576 -> 608 -> 705 triangles, two steps of
    `adapt` with the local bound): Γ0's small bisected facets give the held pressures' rows
    that nearly depend on each other, the ridge's projection left them moving by ~1e-10
    of the step after two passes, and the pressure cap then stopped the descent after 4 of
    its 300 steps (gap 1.50 times the global program's, measured before the change).
    Projected until they move by round-off, the descent runs and the gap is within 1.5 times
    the program's (measured 1.00), certified and at most the upper bound."""
    from dataclasses import replace

    from elastoplast.adapt.loop import AdaptOptions, adapt
    from elastoplast.references.solves import LOCAL_SOLVE_TOL

    problem = ep.problem_from_dict(cylinder_dict(divisions=(24, 12)), base_dir=Path(__file__).parents[1] / "problems")
    run = adapt(problem, AdaptOptions(lower="local", rtol=1e-6, max_iter=3, bracket="never"))
    disc = ep.discretize(replace(problem, mesh=run.meshes[-1]))
    sol = ep.solve(disc, "newton", tol=LOCAL_SOLVE_TOL)
    up = best_upper_bound(disc, sol, method="newton")
    glob = solve_lower_bound(disc)
    lb = local_lower_bound(disc, sol, descent=300)
    assert lb.certified and glob.certified, lb.message
    assert lb.timings["descent_steps"] > 100
    assert up.Pi - lb.lower <= 1.5 * (up.Pi - glob.lower)
    assert lb.lower <= up.Pi


def test_a_held_pressure_moving_by_round_off_does_not_cap_the_step():
    """The cap counts a held pressure's change as round-off against the step's largest
    traction change, not against its pressure changes: a step that moves the pressures
    little (1e-6) and a held one by 1e-17 is taken whole (it was capped to 0 and stopped the
    descent after 3 steps on an adapted cylinder mesh); a held pressure that really moves
    (1e-6, at zero) still caps it to 0, as does an unheld one at zero."""
    from elastoplast.bounds.local.descent import pressure_cap

    t = np.zeros((3, 2, 2))
    t[:, :, 1] = [[0.0, 5.0], [5.0, 5.0], [5.0, 0.0]]
    dt = np.zeros_like(t)
    dt[:, :, 0] = 1.0  # the step moves other tractions by 1
    dt[:, :, 1] = -1e-6
    dt[0, 0, 1] = -1e-17
    contact = np.ones(3, dtype=bool)
    held = np.array([[0, 0], [2, 1]])
    dt[2, 1, 1] = -1e-17
    assert pressure_cap(t, dt, contact, held) == 1.0
    dt[0, 0, 1] = -1e-6
    assert pressure_cap(t, dt, contact, held) == 0.0
    dt[0, 0, 1] = -1e-17
    assert pressure_cap(t, dt, contact, held[1:]) == 0.0


def test_a_pressure_the_cap_brings_to_zero_is_held_from_the_next_step(monkeypatch):
    """A step capped where a pressure reaches zero leaves that pressure held in the steps
    that follow (until the set is found afresh), as if the step had held it. Released, the
    next direction raised it again and the one after it capped the step back to zero: on an
    adaptively refined cylinder mesh (10,867 triangles) the descent alternated so for tens of
    steps at a tenth of a full step, and its gap rule stopped it after 49 steps at a gap of
    4.5e-2 (measured before the change; 3.4e-3 after 300 steps with it, the global program 2.2e-3).
    Checked on the cylinder at 1,600 triangles (100 steps, where 6 pressures reach zero so; the
    rule before the change held none of them): every pressure a step took to zero is among
    those the next step starts holding."""
    import elastoplast.bounds.local.descent as fr
    from elastoplast.references.solves import LOCAL_SOLVE_TOL

    disc = build(cylinder_dict(divisions=(40, 20)))
    sol = ep.solve(disc, "newton", tol=LOCAL_SOLVE_TOL)
    d = disc.dim
    capped, checked = [], []
    cap, fresh = fr.pressure_cap, fr.still_zero

    def spy_cap(t, dt, contact, held):
        capped.append((t.copy(), dt.copy()))
        return cap(t, dt, contact, held)

    def carried(t, pairs, contact):
        if capped:
            t_old, dt = capped[-1]
            lam_old, dlam = t_old[contact, :, d - 1], dt[contact, :, d - 1]
            zeroed = fr.at_zero(t, contact) & ~fr.at_zero(t_old, contact) & (dlam < 0) & (lam_old > 0)
            held = np.zeros_like(zeroed)
            held[pairs[:, 0], pairs[:, 1]] = True
            checked.append((int(zeroed.sum()), int((zeroed & ~held).sum())))
        return fresh(t, pairs, contact)

    monkeypatch.setattr(fr, "pressure_cap", spy_cap)
    monkeypatch.setattr(fr, "still_zero", carried)
    lb = local_lower_bound(disc, sol, 8, descent=100)
    assert lb.certified
    assert sum(z for z, _ in checked) > 0  # some step took a pressure to zero
    assert all(missed == 0 for _, missed in checked)
