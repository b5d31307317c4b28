"""Newton's shortcuts (issue 18) against the computations they replace: a line-search
trial without its gradient, and the tangents from the strains the evaluation kept."""

from __future__ import annotations

import numpy as np

from conftest import build, sphere_quarter_dict
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.linalg.amg import contact_dofs
from elastoplast.solvers.newton import evaluate, line_search, project, to_variables, with_gradient


def full_line_search(disc, cdofs, lower, st, direction, armijo):
    """The line search as it was: every trial with its gradient and its strains formed again."""
    alpha = 1.0
    for _ in range(40):
        trial = project(st.y + alpha * direction, cdofs, lower)
        cand = evaluate(disc, cdofs, trial, tangent=False)
        if cand.energy <= st.energy + armijo * (st.grad @ (trial - st.y)) + 1e-14 * abs(st.energy):
            from dataclasses import replace
            return replace(cand, eps_plastic=None).with_tangent(disc), alpha
        alpha *= 0.5
    return None, alpha


def same_state(a, b):
    for name in ("y", "u", "sigma", "xi", "plastic", "tangent", "grad"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.U == b.U and a.energy == b.energy


def test_line_search_without_trial_gradients_is_the_full_one():
    disc = build(sphere_quarter_dict((5, 5, 4), hardening=2000.0))
    nd, _ = nondimensionalize(disc)
    cdofs = contact_dofs(nd)
    lower = -nd.psi
    rng = np.random.default_rng(7)
    # a point with plastic elements and a long step from it: the search backtracks
    st = evaluate(nd, cdofs, project(to_variables(np.zeros(nd.n_free), 0.0, cdofs), cdofs, lower))
    direction = -st.grad / np.abs(st.grad).max() * (1.0 + 0.1 * rng.random(st.grad.size))
    direction *= 1e3 * np.abs(nd.psi).max() / np.abs(direction).max()
    a, alpha_a = line_search(nd, cdofs, lower, st, direction, 1e-4)
    b, alpha_b = full_line_search(nd, cdofs, lower, st, direction, 1e-4)
    assert alpha_a == alpha_b < 1.0
    same_state(a, b)


def test_gradient_added_later_equals_the_evaluated_one():
    disc = build(sphere_quarter_dict((5, 5, 4), hardening=2000.0))
    nd, _ = nondimensionalize(disc)
    cdofs = contact_dofs(nd)
    y = np.append(np.random.default_rng(1).standard_normal(nd.n_free), -1e-2)
    y[:-1] *= 5.0 * nd.material.yield_stress / np.abs(nd.strain(y[:-1])).max()  # many elements yield
    kept = with_gradient(nd, cdofs, evaluate(nd, cdofs, y, gradient=False))
    assert kept.plastic.size > 0
    same_state(kept, evaluate(nd, cdofs, y))
    # the tangents from the kept strains equal those from the strains formed again
    from dataclasses import replace
    fresh = replace(evaluate(nd, cdofs, y, tangent=False), eps_plastic=None).with_tangent(nd)
    same_state(evaluate(nd, cdofs, y), fresh)
