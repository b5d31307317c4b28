"""Loading paths (Prandtl-Reuss by backward Euler): the physics a path must obey.

Origins of the numbers asserted:

* a one-step path from the unloaded state *is* Hencky's problem (docs/evolution.md):
  the same answer as ``ep.solve`` to the certificate's tolerance;
* the homogeneous block (flat obstacle under the whole bottom, top held in z,
  symmetry faces x = 0 and y = 0 held normally, the other sides free) is in
  uniaxial stress ``-q e_z e_z``, ``q = F / A``, with the closed form
  ``kappa_{n+1} = max(kappa_n, (q_{n+1} - sigma_y) / H, 0)`` and
  ``U_{n+1} = h (q_{n+1} / E + kappa_{n+1})`` for any step sizes (radial return is
  exact on a proportional path): at every step of load, unload and reload;
* elastic increments add up: unloading and reloading to an earlier maximum with no
  element yielding on the way returns to the state at that maximum;
* the dissipation of a step, ``sum |T| sigma : dp``, is >= 0 and xi never decreases
  (normality and the hardening law);
* backward Euler converges at first order: halving the steps of a monotone path
  halves the change of the end point, about;
* the certificate sees the state: a step's answer judged as Hencky's problem fails;
* the step's two objectives, (S_n) centred at the state and (D_n) with the step's
  incremental energy, have opposite optimal values: the duality gap of every
  converged step is small.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.errors import InputError
from elastoplast.references.certified import certified_bounds
from elastoplast.solvers.path import check_path

E, NU, SY, H = 200e3, 0.3, 250.0, 20e3
HEIGHT, AREA = 2.0, 4.0


def block(divisions=(3, 3, 3)) -> ep.Discretization:
    return ep.discretize(ep.problem_from_dict({
        "mesh": {"generator": "box", "size": [2.0, 2.0, HEIGHT], "divisions": list(divisions), "grading": 1.5,
                 "contact_radius": 10.0},
        "material": {"E": E, "nu": NU, "yield_stress": SY, "hardening": H},
        "boundary": {"clamped": [], "contact": ["bottom"], "fix_component": {"x": ["xmin"], "y": ["ymin"], "z": ["top"]}},
        "obstacle": {"shape": "flat"},
        "load": {"force": 1.0},
    }))


def cylinder(divisions=(24, 12), force=6000.0) -> ep.Discretization:
    return ep.discretize(ep.problem_from_dict({
        "mesh": {"generator": "rectangle", "size": [20.0, 10.0], "divisions": list(divisions), "grading": 2.0,
                 "contact_radius": 4.0},
        "material": {"E": E, "nu": NU, "yield_stress": 1200.0, "hardening": 10000.0},
        "boundary": {"clamped": ["xmin", "xmax", "top"], "contact": ["contact"]},
        "obstacle": {"shape": "cylinder", "radius": 10.0},
        "load": {"force": force},
    }))


def block_closed_form(pressures) -> list[tuple[float, float]]:
    """``(U, kappa)`` after each step of the homogeneous block (module docstring)."""
    out, kappa = [], 0.0
    for q in pressures:
        kappa = max(kappa, (q - SY) / H, 0.0)
        out.append((HEIGHT * (q / E + kappa), kappa))
    return out


#: load past yield, unload to almost nothing, reload to the maximum and beyond
BLOCK_PRESSURES = np.array([0.5, 1.2, 1.6, 1.0, 0.3, 0.05, 1.0, 1.6, 2.0]) * SY
METHODS = [("conic", {}), ("conic-cvxpy", {}), ("conic-displacement", {}), ("newton", {}), ("uzawa", {}),
           ("uzawa-fast", {}), ("uzawa-fast", {"variant": "alg2"})]


@pytest.mark.parametrize("method,extra", METHODS, ids=[m + "-" + "-".join(e.values()) for m, e in METHODS])
def test_homogeneous_block_follows_the_closed_form_at_every_step(method, extra):
    disc = block()
    tol = 1e-8
    res = ep.solve_path(disc, BLOCK_PRESSURES * AREA, method, tol=tol, **extra)
    assert res.converged, [s.solution.message for s in res.steps]
    for step, (U, kappa) in zip(res.steps, block_closed_form(BLOCK_PRESSURES)):
        assert step.solution.kkt.worst <= tol
        assert step.solution.duality_gap <= 1e-6, step.index
        # the certificate's tolerance bounds the relative error of U, up to conditioning
        assert step.U == pytest.approx(U, rel=100 * tol), step.index
        assert np.allclose(step.kappa, kappa, rtol=1e-6, atol=1e-6 * SY / E)
        assert np.allclose(step.solution.xi, H * kappa, rtol=1e-6, atol=1e-6 * SY)
        assert np.allclose(step.solution.sigma[:, 2], -BLOCK_PRESSURES[step.index - 1], rtol=1e-6, atol=1e-6 * SY)
    # the three steps past the earlier maximum are the only ones that yield
    assert [s.yielding > 0 for s in res.steps] == [False, True, True, False, False, False, False, False, True]
    assert res.residual_imprint() == pytest.approx(HEIGHT * (BLOCK_PRESSURES[5] / E + (1.6 * SY - SY) / H), rel=1e-6)


@pytest.mark.parametrize("method", ["conic", "newton"])
def test_a_one_step_path_is_the_hencky_problem(method):
    disc = cylinder()
    tol = 1e-9
    hencky = ep.solve(disc, method, tol=tol)
    step = ep.solve_path(disc, [disc.force], method, tol=tol).steps[0]
    assert hencky.converged and step.converged
    assert step.U == pytest.approx(hencky.U, rel=100 * tol)
    scale = np.abs(hencky.sigma).max()
    assert np.abs(step.solution.sigma - hencky.sigma).max() <= 1e3 * tol * scale
    assert np.allclose(step.u, hencky.u, rtol=0, atol=100 * tol * np.abs(hencky.u).max())


def test_unloading_and_reloading_elastically_returns_to_the_same_state():
    disc = cylinder()
    F = disc.force
    path = [0.5 * F, F, 0.5 * F, 0.05 * F, 0.5 * F, F]
    tol = 1e-9
    for method in ("conic", "newton"):
        res = ep.solve_path(disc, path, method, tol=tol)
        assert res.converged
        steps = res.steps
        assert steps[1].yielding > 0
        assert all(s.yielding == 0 for s in steps[2:]), [s.yielding for s in steps]  # no element yields again
        assert steps[5].U == pytest.approx(steps[1].U, rel=100 * tol)
        scale = np.abs(steps[1].solution.sigma).max()
        assert np.abs(steps[5].solution.sigma - steps[1].solution.sigma).max() <= 1e3 * tol * scale
        assert steps[5].solution.xi == pytest.approx(steps[1].solution.xi, abs=1e3 * tol * 1200.0)
        # the imprint stays after unloading: more than the elastic share of the last unloading step
        assert steps[3].U > 0.05 * steps[1].U


def test_reverse_yielding_is_reported_and_both_formulations_agree_on_it():
    disc = cylinder(force=16000.0)
    F = disc.force
    tol = 1e-9
    runs = {m: ep.solve_path(disc, [0.5 * F, F, 0.5 * F, 0.01 * F], m, tol=tol) for m in ("conic", "newton")}
    for res in runs.values():
        assert res.converged
        assert [s.unloading for s in res.steps] == [False, False, True, True]
        assert res.steps[2].reverse_yield == res.steps[2].yielding
        assert res.steps[0].reverse_yield == res.steps[1].reverse_yield == 0
    a, b = (runs[m].steps for m in ("conic", "newton"))
    for sa, sb in zip(a, b):
        assert sa.U == pytest.approx(sb.U, rel=1e-6)
    # reverse yielding happens here (a deep plastic zone unloaded): reported by both, on the same elements
    assert a[2].reverse_yield > 0
    big = a[2].dkappa > 1e-3 * a[2].dkappa.max()
    assert np.array_equal(big, b[2].dkappa > 1e-3 * b[2].dkappa.max())


def test_dissipation_is_nonnegative_and_hardening_never_decreases():
    disc = cylinder(force=16000.0)
    F = disc.force
    tol = 1e-8
    res = ep.solve_path(disc, [0.3 * F, 0.7 * F, F, 0.4 * F, 0.02 * F, 0.8 * F, 1.1 * F], "conic", tol=tol)
    assert res.converged
    work_scale = max(abs(s.plastic_work) for s in res.steps)
    xi_before = np.zeros(disc.n_elements)
    for s in res.steps:
        assert s.plastic_work >= -1e3 * tol * work_scale, s.index
        assert np.all(s.solution.xi >= xi_before - 1e3 * tol * 1200.0), s.index
        assert np.all(s.dkappa >= 0.0)
        xi_before = s.solution.xi
    assert res.steps[2].plastic_work > 0 and res.steps[6].plastic_work > 0


def test_time_step_refinement_of_a_monotone_path_converges_at_first_order():
    disc = cylinder()
    F = disc.force
    ends = []
    for n in (4, 8, 16, 32, 64):
        res = ep.solve_path(disc, list(np.linspace(F / n, F, n)), "newton", tol=1e-10)
        assert res.converged
        ends.append(res.steps[-1].U)
    changes = np.abs(np.diff(ends))
    ratios = changes[:-1] / changes[1:]
    # first order: each halving divides the change by about 2 (irregular: elements
    # yield and nodes touch one at a time); the last ratios settle
    assert np.all(changes[1:] < changes[:-1])
    assert 1.4 <= np.exp(np.mean(np.log(ratios[-2:]))) <= 2.8, ratios


def test_warm_and_cold_starts_give_the_same_path():
    disc = cylinder()
    F = disc.force
    path = list(np.linspace(F / 6, F, 6)) + [0.4 * F, 0.8 * F]
    for method in ("newton", "uzawa-fast"):
        warm = ep.solve_path(disc, path, method, tol=1e-8)
        cold = ep.solve_path(disc, path, method, tol=1e-8, warm_start=False)
        assert warm.converged and cold.converged
        assert all(s.warm_started for s in warm.steps[1:]) and not any(s.warm_started for s in cold.steps)
        assert np.allclose(warm.U, cold.U, rtol=1e-6)


def test_the_certificate_sees_the_state():
    """A reloading step's answer is no answer of Hencky's problem at the same force:
    judged without the state (the step's problem with state and obstacle shift
    dropped), its residuals are large."""
    from dataclasses import replace

    disc = cylinder()
    F = disc.force
    res = ep.solve_path(disc, [F, 0.3 * F], "newton", tol=1e-9)
    step = res.steps[1]
    assert step.solution.kkt.worst <= 1e-9
    hencky_disc = disc.with_force(0.3 * F)
    wrong = ep.certify(hencky_disc, step.solution.sigma, step.solution.xi, step.u, step.U)
    assert wrong.worst > 1e-3
    # and the state alone matters too: the step's obstacle without its state
    stepped = disc.step(0.3 * F, ep.Prestate.of(disc.material, res.steps[0].solution.sigma,
                                                 res.steps[0].solution.xi), disc.free_displacement(res.steps[0].u))
    assert ep.certify(stepped, step.solution.sigma, step.solution.xi, step.solution.u, step.U).worst <= 1e-9
    assert ep.certify(replace(stepped, state=None), step.solution.sigma, step.solution.xi, step.solution.u,
                      step.U).worst > 1e-3


def test_a_failed_step_ends_the_path():
    disc = cylinder()
    F = disc.force
    res = ep.solve_path(disc, [0.5 * F, F, 0.5 * F], "newton", tol=1e-10, max_iter=1)
    assert not res.converged
    assert len(res.steps) < 3 and not res.steps[-1].converged


@pytest.mark.parametrize("bad,why", [
    ([], "empty"), ([1.0, 0.0], "entry 2"), ([1.0, -2.0], "entry 2"), ([float("nan")], "entry 1"),
    (["1"], "entry 1"), ([True], "entry 1"), ("1, 2", "list"), (3.0, "list"), ({"a": 1}, "list"),
])
def test_bad_paths_are_refused_naming_the_entry(bad, why):
    with pytest.raises(InputError, match=why):
        check_path(bad)
    with pytest.raises(InputError) as err:
        ep.solve_path(block(), bad, "newton")
    assert err.value.field == "forces"


def test_a_step_is_no_start_for_a_path():
    disc = block()
    stepped = disc.step(1.0, ep.Prestate.of(disc.material, np.zeros((disc.n_elements, disc.k)),
                                            np.zeros(disc.n_elements)), np.zeros(disc.n_free))
    with pytest.raises(InputError, match="already a step"):
        ep.solve_path(stepped, [1.0], "newton")


def independent_path(disc: ep.Discretization, forces) -> list[float]:
    """U after each step from a model written here from the *minimum* form of the
    step's incremental energy (docs/evolution.md), not the package's sup form:

        W_n(de) = min over tr dp = 0, sqrt(2/3)|dp| <= dk of
                  1/2 C(de - dp):(de - dp) + sigma_n:(de - dp) + (sigma_y + xi_n) dk + 1/2 H dk^2,

    minimised with -F V over the total-gap contact set in CVXPY, the state
    carried by this function (sigma_{n+1} = sigma_n + C(de - dp), xi_{n+1} = xi_n + H dk)."""
    import cvxpy as cp

    m, n, k = disc.material, disc.n_elements, disc.k
    C = m.stiffness(disc.dim)
    Lc = np.linalg.cholesky(C)
    vol = disc.volumes
    sigma, xi, u = np.zeros((n, k)), np.zeros(n), np.zeros(disc.n_free)
    trace = np.zeros(k)
    trace[:3] = 1.0
    out = []
    for F in forces:
        dv, V = cp.Variable(disc.n_free), cp.Variable()
        dp, dk = cp.Variable((n, k)), cp.Variable(n)
        de = cp.reshape(disc.B @ dv, (n, k), order="C")
        el = de - dp
        energy = (0.5 * cp.sum(vol @ cp.square(el @ Lc)) + cp.sum(cp.multiply(vol[:, None] * sigma, el))
                  + (vol * (m.yield_stress + xi)) @ dk + 0.5 * m.hardening * (vol @ cp.square(dk)))
        cons = [dp @ trace == 0, cp.SOC(dk, np.sqrt(2.0 / 3.0) * dp.T, axis=0),
                disc.N @ (u + dv) + disc.psi - V >= 0]
        cp.Problem(cp.Minimize(energy - F * V), cons).solve(solver=cp.CLARABEL, tol_gap_abs=1e-10,
                                                            tol_gap_rel=1e-10, tol_feas=1e-10)
        sigma = sigma + (de.value - dp.value) @ C
        xi = xi + m.hardening * dk.value
        u = u + dv.value
        out.append(float(V.value))
    return out


def quarter_sphere() -> ep.Discretization:
    """The shipped 3D quarter model (two symmetry planes), coarsened."""
    data = ep.read_toml("problems/sphere_quarter_3d.toml")
    data["mesh"]["divisions"] = [6, 6, 4]
    return ep.discretize(ep.problem_from_dict(data, base_dir="problems"))


@pytest.mark.parametrize("case", ["cylinder_2d", "quarter_sphere_3d"])
def test_paths_agree_with_an_independent_incremental_model(case, monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parent.parent)
    disc = cylinder(divisions=(16, 8), force=16000.0) if case == "cylinder_2d" else quarter_sphere()
    F = disc.force
    # load, unload to almost nothing, reload beyond the earlier maximum (within small strains)
    top = 1.5 if case == "quarter_sphere_3d" else 1.1
    path = [0.4 * F, F, top * F, 0.3 * F, 0.05 * F, 0.7 * F, 1.2 * top * F]
    reference = independent_path(disc, path)
    for method in ("conic", "newton"):
        res = ep.solve_path(disc, path, method, tol=1e-9)
        assert res.converged
        assert np.allclose(res.U, reference, rtol=1e-5, atol=0), (method, res.U, reference)


def test_hidden_sub_steps_are_refused():
    with pytest.raises(InputError) as err:
        ep.solve_path(block(), [1.0, 2.0], "newton", load_steps=3)
    assert err.value.field == "load_steps" and "intermediate forces" in err.value.message


@pytest.mark.parametrize("method", ["clarabel-export", "osqp-elastic"])
def test_methods_that_serve_hencky_only_refuse_a_step(method):
    """The exported program and the elastic QP hold no state: a step is refused
    naming the discretisation, never answered as Hencky's problem."""
    disc = block()
    q = 1.2 * SY
    with pytest.raises(InputError) as err:
        ep.solve_path(disc, [q * AREA], method)
    assert err.value.field == "disc" and "loading path" in err.value.message


def test_small_strains_are_judged_on_the_total_displacement():
    """Each step of a slow monotone overload adds little strain, but the total
    leaves the small-strain model: a step there is not converged (the limit is
    fem.locking.SMALL_STRAIN_LIMIT; the block's axial strain is q/E + kappa)."""
    from elastoplast.fem.locking import SMALL_STRAIN_LIMIT

    disc = block()
    q_end = SY + H * 2 * SMALL_STRAIN_LIMIT  # kappa = 2 x the limit at the last step
    qs = np.linspace(SY, q_end, 12)[1:]
    res = ep.solve_path(disc, qs * AREA, "newton", tol=1e-8)
    assert not res.converged
    last = res.steps[-1]
    assert "small-strain" in last.solution.message
    strain = (qs[last.index - 1] / E + (qs[last.index - 1] - SY) / H)
    assert strain > SMALL_STRAIN_LIMIT
    # every step before it stayed within the model
    assert all(s.converged for s in res.steps[:-1])


def test_a_path_problem_is_not_solved_as_hencky_s():
    """ep.solve on a problem file's path would answer another problem (Hencky's at the
    largest force): refused, pointing to solve_path."""
    problem = ep.problem_from_dict({
        "mesh": {"generator": "box", "size": [2.0, 2.0, HEIGHT], "divisions": [2, 2, 2], "contact_radius": 10.0},
        "material": {"E": E, "nu": NU, "yield_stress": SY, "hardening": H},
        "boundary": {"clamped": [], "contact": ["bottom"], "fix_component": {"x": ["xmin"], "y": ["ymin"], "z": ["top"]}},
        "obstacle": {"shape": "flat"},
        "load": {"path": [1.2 * SY * AREA, 0.5 * SY * AREA]},
    })
    disc = ep.discretize(problem)
    with pytest.raises(InputError, match="solve_path") as err:
        ep.solve(disc, "newton")
    assert err.value.field == "disc"
    res = ep.solve_path(disc, problem.path, "newton", tol=1e-8)
    expected = block_closed_form([1.2 * SY, 0.5 * SY])
    assert np.allclose(res.U, [u for u, _ in expected], rtol=1e-6)


@pytest.mark.parametrize("entry", ["upper", "lower", "certified", "limit"])
def test_the_bounds_refuse_a_step_and_a_path(entry):
    """The continuum bounds are Hencky's: a step of a path (which carries a state) and a
    problem file's path are refused naming the discretisation, not bounded as Hencky's
    problem at some force."""
    disc = block()
    stepped = disc.step(1.2 * SY * AREA, ep.Prestate.of(disc.material, np.zeros((disc.n_elements, disc.k)),
                                                          np.zeros(disc.n_elements)), np.zeros(disc.n_free))
    path_disc = ep.discretize(replace_path(disc.problem))
    run = {
        "upper": lambda d: ep.upper_bound(d, (np.zeros((d.mesh.n_nodes, d.dim)), 0.0)),
        "lower": lambda d: ep.solve_lower_bound(d),
        "certified": lambda d: certified_bounds(d),
        "limit": lambda d: ep.static_limit_load(d),
    }[entry]
    for d, why in ((stepped, "step of a loading path"), (path_disc, "load.path")):
        with pytest.raises(InputError, match=why) as err:
            run(d)
        assert err.value.field == "disc"


def replace_path(problem):
    from dataclasses import replace

    return replace(problem, path=(problem.force, 0.5 * problem.force))
