"""Bad input to the Python API: every documented function refuses a wrong type, ``None``,
a wrong length or another mesh's object with an ``InputError`` naming the argument,
never a ``TypeError``, ``AttributeError``, ``IndexError`` or numpy error from deep
inside. Each case names the exact call that failed that way before, and the field the
error must name; the calls done right still work; the iterative methods stop on a
non-finite iterate without numpy's floating-point warnings."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.solvers.accelerated import solve_accelerated, solve_alg2, solve_uzawa_fast
from elastoplast.solvers.loop import Monitor

from conftest import build, cylinder_dict


@pytest.fixture(scope="module")
def case():
    """A 64-triangle cylinder, its conic solution, a solution of another mesh (100
    triangles) and the bisection state of a refinement of the first mesh."""
    disc = build(cylinder_dict((8, 4)))
    other = build(cylinder_dict((10, 5)))
    _, state, _ = ep.refine(disc.mesh, [0])
    return {"disc": disc, "sol": ep.solve(disc, "conic"), "other": ep.solve(other, "conic"), "state": state}


def _calls(c):
    disc, sol, other, state = c["disc"], c["sol"], c["other"], c["state"]
    z = np.zeros

    def nan_start():
        return dataclasses.replace(sol, u=np.full_like(sol.u, np.nan))

    return {
        # warm starts of another mesh: IndexError / AttributeError, or a start read in the wrong places
        "solve_newton(warm_start=other mesh)": (lambda: ep.solve_newton(disc, warm_start=other), "warm_start"),
        "solve_newton(warm_start='x')": (lambda: ep.solve_newton(disc, warm_start="x"), "warm_start"),
        "solve_newton(warm_start=nan)": (lambda: ep.solve_newton(disc, warm_start=nan_start()), "warm_start"),
        "solve_uzawa(initial=other mesh)": (lambda: ep.solve_uzawa(disc, ep.UzawaOptions(initial=other)), "initial"),
        "solve_uzawa(initial=nan)": (lambda: ep.solve_uzawa(disc, ep.UzawaOptions(initial=nan_start())), "initial"),
        "solve(uzawa, initial=other mesh)": (lambda: ep.solve(disc, "uzawa", initial=other), "initial"),
        # a disc or options that are not: AttributeError in loop.py, uzawa.py, conic.py
        "solve_newton(None)": (lambda: ep.solve_newton(None), "disc"),
        "solve_newton(disc, 'x')": (lambda: ep.solve_newton(disc, "x"), "options"),
        "solve_newton(disc, {'load_steps': 0})": (lambda: ep.solve_newton(disc, {"load_steps": 0}),
                                                  "options.load_steps"),
        "solve_uzawa(None)": (lambda: ep.solve_uzawa(None), "disc"),
        "solve_uzawa(disc, 'x')": (lambda: ep.solve_uzawa(disc, "x"), "options"),
        "solve_uzawa(disc, NewtonOptions())": (lambda: ep.solve_uzawa(disc, ep.NewtonOptions()), "options"),
        "solve_uzawa_fast(None)": (lambda: solve_uzawa_fast(None), "disc"),
        "solve_uzawa_fast(disc, 'x')": (lambda: solve_uzawa_fast(disc, "x"), "options"),
        "solve_alg2(disc, 5)": (lambda: solve_alg2(disc, 5), "options"),
        "solve_accelerated(None)": (lambda: solve_accelerated(None), "disc"),
        "solve_conic(None)": (lambda: ep.solve_conic(None), "disc"),
        "solve_conic(disc, 'x')": (lambda: ep.solve_conic(disc, "x"), "options"),
        "solve_conic_cvxpy(None)": (lambda: ep.solve_conic_cvxpy(None), "disc"),
        "solve_conic_displacement(disc, 1)": (lambda: ep.solve_conic_displacement(disc, 1), "options"),
        # load_sweep: TypeError for a forces that is not a sequence, AttributeError for options
        "load_sweep(disc, None)": (lambda: ep.load_sweep(disc, None), "forces"),
        "load_sweep(disc, 5.0)": (lambda: ep.load_sweep(disc, 5.0), "forces"),
        "load_sweep(disc, '12')": (lambda: ep.load_sweep(disc, "12"), "forces"),
        "load_sweep(disc, 2-D array)": (lambda: ep.load_sweep(disc, np.ones((2, 2))), "forces"),
        "load_sweep(disc, ['a'])": (lambda: ep.load_sweep(disc, ["a"]), "forces[0]"),
        "load_sweep(disc, [1, -1])": (lambda: ep.load_sweep(disc, [1.0, -1.0]), "forces[1]"),
        "load_sweep(disc, [True])": (lambda: ep.load_sweep(disc, [True]), "forces[0]"),
        "load_sweep(disc, [1], 'x')": (lambda: ep.load_sweep(disc, [1.0], "x"), "options"),
        "load_sweep(initial=other mesh)": (lambda: ep.load_sweep(disc, [1.0], {"initial": other}), "initial"),
        # options: dict('x') raised ValueError
        "solve(disc, conic, options='x')": (lambda: ep.solve(disc, "conic", options="x"), "options"),
        "method_options(conic, 'x')": (lambda: ep.method_options("conic", "x"), "options"),
        "method_options(newton, ['tol'])": (lambda: ep.method_options("newton", ["tol"]), "options"),
        "method_options(uzawa, initial='x')": (lambda: ep.method_options("uzawa", {"initial": "x"}), "initial"),
        # ranges: 1e-300 "diverged" at iteration 0, or overflowed with raw numpy warnings
        "UzawaOptions(divergence_factor=1e-300)": (lambda: ep.UzawaOptions(divergence_factor=1e-300),
                                                   "divergence_factor"),
        "UzawaOptions(divergence_factor=0.5)": (lambda: ep.UzawaOptions(divergence_factor=0.5), "divergence_factor"),
        "UzawaOptions(rigid_weight=1e-300)": (lambda: ep.UzawaOptions(rigid_weight=1e-300), "rigid_weight"),
        "UzawaOptions(rigid_weight=1e300)": (lambda: ep.UzawaOptions(rigid_weight=1e300), "rigid_weight"),
        "FastOptions(penalty=1e-300)": (lambda: ep.FastOptions(penalty=1e-300), "penalty"),
        "FastOptions(penalty=1e300)": (lambda: ep.FastOptions(penalty=1e300), "penalty"),
        # certify: UFuncTypeError, TypeError, ValueError, AttributeError
        "certify(U='x')": (lambda: ep.certify(disc, sol.sigma, sol.xi, sol.u, "x"), "U"),
        "certify(U=None)": (lambda: ep.certify(disc, sol.sigma, sol.xi, sol.u, None), "U"),
        "certify(U=True)": (lambda: ep.certify(disc, sol.sigma, sol.xi, sol.u, True), "U"),
        "certify(U=[1.0])": (lambda: ep.certify(disc, sol.sigma, sol.xi, sol.u, [1.0]), "U"),
        "certify(sigma='a')": (lambda: ep.certify(disc, "a", sol.xi, sol.u, sol.U), "sigma"),
        "certify(xi=None)": (lambda: ep.certify(disc, sol.sigma, None, sol.u, sol.U), "xi"),
        "certify(u=short)": (lambda: ep.certify(disc, sol.sigma, sol.xi, z(3), sol.U), "u"),
        "certify(contact_force='x')": (lambda: ep.certify(disc, sol.sigma, sol.xi, sol.u, sol.U, "x"),
                                       "contact_force"),
        "certify(None, ...)": (lambda: ep.certify(None, sol.sigma, sol.xi, sol.u, sol.U), "disc"),
        # refinement: AttributeError, ValueError, IndexError; theta='0.5' accepted
        "refine(mesh, [0], state='x')": (lambda: ep.refine(disc.mesh, [0], state="x"), "state"),
        "dorfler_mark(['a'], 0.5)": (lambda: ep.dorfler_mark(["a"], 0.5), "indicators"),
        "dorfler_mark(None, 0.5)": (lambda: ep.dorfler_mark(None, 0.5), "indicators"),
        "dorfler_mark(eta, '0.5')": (lambda: ep.dorfler_mark(np.ones(3), "0.5"), "theta"),
        "dorfler_mark(eta, None)": (lambda: ep.dorfler_mark(np.ones(3), None), "theta"),
        "dorfler_mark(eta, True)": (lambda: ep.dorfler_mark(np.ones(3), True), "theta"),
        "prolong_p1(None, None)": (lambda: ep.prolong_p1(None, None), "state"),
        "prolong_p1(mesh, u)": (lambda: ep.prolong_p1(disc.mesh, sol.u), "state"),
        "prolong_p1(state, None)": (lambda: ep.prolong_p1(state, None), "values"),
        "prolong_p1(state, 1.0)": (lambda: ep.prolong_p1(state, 1.0), "values"),
        "prolong_p1(state, 'x')": (lambda: ep.prolong_p1(state, "x"), "values"),
        "shape_quality(None)": (lambda: ep.shape_quality(None), "mesh"),
        # upper_bound: TypeError, ValueError (unpacking, reshape, float), AttributeError
        "upper_bound(disc, None)": (lambda: ep.upper_bound(disc, None), "candidate"),
        "upper_bound(disc, 'x')": (lambda: ep.upper_bound(disc, "x"), "candidate"),
        "upper_bound(disc, other mesh)": (lambda: ep.upper_bound(disc, other), "candidate"),
        "upper_bound(disc, (short u, U))": (lambda: ep.upper_bound(disc, (z(3), 0.0)), "candidate.u"),
        "upper_bound(disc, (u, 'x'))": (lambda: ep.upper_bound(disc, (sol.u, "x")), "candidate.U"),
        "upper_bound(None, sol)": (lambda: ep.upper_bound(None, sol), "disc"),
        # summary: IndexError, AttributeError
        "summary(disc, other mesh)": (lambda: ep.summary(disc, other), "sol"),
        "summary(disc, None)": (lambda: ep.summary(disc, None), "sol"),
        "summary(None, sol)": (lambda: ep.summary(None, sol), "disc"),
        # with_force: '1000' and True were accepted (float() coerces)
        "disc.with_force('1000')": (lambda: disc.with_force("1000"), "load.force"),
        "disc.with_force(True)": (lambda: disc.with_force(True), "load.force"),
        "disc.with_force(None)": (lambda: disc.with_force(None), "load.force"),
        "problem.with_force('1000')": (lambda: disc.problem.with_force("1000"), "load.force"),
        "problem.with_force(0)": (lambda: disc.problem.with_force(0), "load.force"),
    }


@pytest.mark.parametrize("name", list(_calls(dict.fromkeys(("disc", "sol", "other", "state")))))
def test_bad_arguments_are_refused_naming_them(case, name):
    call, field = _calls(case)[name]
    with pytest.raises(ep.InputError) as exc:
        call()
    assert exc.value.field == field, exc.value


def test_the_same_functions_called_right_still_work(case):
    """Mappings, ``None`` for default options, lists, numpy scalars and arrays, a warm
    start interpolated from the coarser mesh: all accepted as documented."""
    disc, sol = case["disc"], case["sol"]
    assert ep.solve_newton(disc, None).converged
    assert ep.solve_uzawa(disc, {"tol": 1e-6}).converged
    warm = ep.solve_uzawa(disc.with_force(np.float64(1.1 * disc.force)), ep.UzawaOptions(initial=sol))
    assert warm.converged
    sweep = ep.load_sweep(disc, np.array([0.5, 1.0]) * disc.force, None)
    assert [s.converged for s in sweep] == [True, True] and abs(sweep[-1].U - sol.U) <= 1e-5 * sol.U
    kkt = ep.certify(disc, sol.sigma.tolist(), sol.xi.tolist(), sol.u.tolist(), np.array(sol.U))
    assert kkt.worst <= 1e-6
    free = ep.upper_bound(disc, (disc.free_displacement(sol.u), sol.U))
    assert free.Pi == pytest.approx(ep.upper_bound(disc, sol).Pi, rel=1e-12)
    assert ep.summary(disc, sol)["n_nodes"] == disc.mesh.n_nodes
    assert ep.dorfler_mark(np.array([1.0, 3.0, 2.0]), 1).tolist() == [True, True, True]
    assert ep.dorfler_mark([1, 3, 2], 0).tolist() == [False, False, False]  # integers; theta = 0 marks nothing
    assert disc.problem.with_force(2).force == 2.0 and disc.with_force(np.int64(3)).force == 3.0
    opts = ep.method_options("uzawa", None)
    assert opts == ep.UzawaOptions() and ep.UzawaOptions(divergence_factor=1.0).divergence_factor == 1.0

    # Newton from the conic solution interpolated onto a refined mesh (what adapt does)
    mesh, state, _ = ep.refine(disc.mesh, np.ones(disc.n_elements, dtype=bool))
    fine = ep.discretize(dataclasses.replace(disc.problem, mesh=mesh))
    start = dataclasses.replace(sol, u=ep.prolong_p1(state, sol.u))
    assert ep.solve_newton(fine, {"tol": 1e-8}, warm_start=start).converged
    with pytest.raises(ep.InputError) as exc:  # Uzawa reads the contact forces too: refused, saying why
        ep.solve_uzawa(fine, ep.UzawaOptions(initial=start))
    assert exc.value.field == "initial" and "contact_force" in exc.value.message


def test_a_residual_growing_divergence_factor_times_stops_the_run(case):
    """The divergence test itself, now that factors below 1 are refused: a candidate
    whose worst residual is more than ``divergence_factor`` times the first one's
    ends the run as DIVERGED."""
    disc, sol = case["disc"], case["sol"]
    nd, units = nondimensionalize(disc)
    options = ep.UzawaOptions(divergence_factor=10.0)
    monitor = Monitor("uzawa", disc, nd, units, options, divergence_factor=options.divergence_factor)  # as Uzawa
    sigma, xi = sol.sigma / units.stress, sol.xi / units.stress
    u, U = disc.free_displacement(sol.u) / units.displacement, sol.U / units.displacement
    assert monitor.check(0, 2.0 * sigma, xi, u, U) is None  # force balance 1: on
    assert monitor.check(1, 5.0 * sigma, xi, u, U) is None  # 4: not ten times 1
    verdict = monitor.check(2, 50.0 * sigma, xi, u, U)  # 49
    assert verdict is not None and verdict.status is ep.Status.DIVERGED and "grew" in verdict.message


@pytest.mark.parametrize("method", ["uzawa", "newton"])
def test_an_overflowing_start_diverges_without_floating_point_warnings(case, method):
    """A finite start whose scaled values overflow: the monitor reports DIVERGED at
    iteration 0; numpy's RuntimeWarnings (overflow, invalid value) stay inside."""
    disc, sol = case["disc"], case["sol"]
    start = dataclasses.replace(sol, u=sol.u * 1e300)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        if method == "uzawa":
            out = ep.solve_uzawa(disc, ep.UzawaOptions(initial=start, max_iter=20))
        else:
            out = ep.solve_newton(disc, warm_start=start)
    assert out.status is ep.Status.DIVERGED, out.message


def test_the_penalty_at_its_bounds_runs_without_floating_point_warnings(case):
    """ALG2 with r = 1e-300 overflowed to inf in five iterations with raw numpy warnings;
    the admitted extremes run (and stall, honestly) without them."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for r in (1e-8, 1e8):
            out = solve_alg2(case["disc"], ep.FastOptions(variant="alg2", penalty=r, max_iter=20))
            assert out.status in (ep.Status.MAX_ITERATIONS, ep.Status.CONVERGED), out.message


def _bound_calls(c):
    """The bounds' and the result type's entry points (each raised a Python error before)."""
    from elastoplast.bounds.bracket import choose_delta, combine, u_bracket
    from elastoplast.bounds.static import certify_static, dual_energy
    from elastoplast.bounds.upper import hencky_energy_density, penetration_bound

    disc, sol, other = c["disc"], c["sol"], c["other"]
    other_disc = build(cylinder_dict((10, 5)))
    return {
        "u_bracket(delta='1')": (lambda: u_bracket(disc, "1", lambda F: (0.0, 0.0)), "delta"),
        "u_bracket(solve_bounds_at=None)": (lambda: u_bracket(disc, 1.0, None), "solve_bounds_at"),
        "choose_delta('1', ...)": (lambda: choose_delta("1", 1.0, 1.0), "force"),
        "combine(None, lower)": (lambda: combine(None, ep.solve_lower_bound(disc)), "upper"),
        "combine(upper, lower of another mesh)": (
            lambda: combine(ep.upper_bound(disc, sol), ep.solve_lower_bound(other_disc)), "lower"),
        "energy_bounds(disc, solution of another mesh)": (lambda: ep.energy_bounds(disc, other), "solution"),
        "penetration_bound(disc, short u)": (lambda: penetration_bound(disc, np.zeros(3), 0.0), "u"),
        "penetration_bound(disc, u, U='x')": (lambda: penetration_bound(disc, sol.u, "x"), "U"),
        "hencky_energy_density(material, None)": (lambda: hencky_energy_density(disc.material, None), "eps"),
        "certify_static(disc, 'x')": (lambda: certify_static(disc, "x"), "field"),
        "dual_energy(another mesh, field)": (lambda: dual_energy(other_disc, ep.solve_lower_bound(disc).field),
                                             "field"),
        "make_solution(status='converged')": (
            lambda: ep.make_solution(disc, method="mine", status="converged", sigma=sol.sigma, xi=sol.xi,
                                     u_free=disc.free_displacement(sol.u), U=sol.U, iterations=0, timings={}),
            "status"),
        "make_solution(short u_free)": (
            lambda: ep.make_solution(disc, method="mine", status=ep.Status.CONVERGED, sigma=sol.sigma, xi=sol.xi,
                                     u_free=np.zeros(3), U=sol.U, iterations=0, timings={}), "u_free"),
    }


BOUND_CALLS = [
    "u_bracket(delta='1')", "u_bracket(solve_bounds_at=None)", "choose_delta('1', ...)", "combine(None, lower)",
    "combine(upper, lower of another mesh)", "energy_bounds(disc, solution of another mesh)",
    "penetration_bound(disc, short u)", "penetration_bound(disc, u, U='x')", "hencky_energy_density(material, None)",
    "certify_static(disc, 'x')", "dual_energy(another mesh, field)", "make_solution(status='converged')",
    "make_solution(short u_free)"]


def test_every_bound_call_is_listed(case):
    assert sorted(BOUND_CALLS) == sorted(_bound_calls(case))


@pytest.mark.parametrize("name", BOUND_CALLS)
def test_bounds_and_results_refuse_bad_arguments(case, name):
    call, field = _bound_calls(case)[name]
    with pytest.raises(ep.InputError) as exc:
        call()
    assert exc.value.field == field, exc.value


def test_a_discretization_cannot_be_edited_in_place(case):
    """Found in the third pass: `d.mesh.points[:] *= 2` then a solve gave the old answer,
    converged (B was built from the old points), and `d.psi[:] = -1` bypassed psi >= 0.
    The arrays operators are built from are read-only views; a changed problem is a new one."""
    disc = case["disc"]
    for name, array in [("points", disc.mesh.points), ("cells", disc.mesh.cells), ("psi", disc.psi),
                        ("volumes", disc.volumes), ("B.data", disc.B.data)]:
        with pytest.raises(ValueError, match="read-only"):
            array[...] = 0
    points = np.array(disc.mesh.points)  # the caller's own copy stays writable
    points *= 2.0
    assert ep.Mesh(points, disc.mesh.cells, dict(disc.mesh.groups)).points.base is points
