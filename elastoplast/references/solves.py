"""The P1 solves the certified bounds need, run above the bounds layer (docs/architecture.md).

The bounds of :mod:`elastoplast.bounds` are computed from solutions they are given; what
solves and then bounds lives here: the solution of the problem with the conservative
obstacle whose upper bound may be smaller (:func:`best_upper_bound`), the solutions at
other loads (:func:`solve_at`, the U bracket's with the local lower bound), the solution
accurate enough for the local lower bound (:func:`local_solution`), and the slope
``dU/dF`` that chooses the U bracket's delta (:func:`displacement_slope`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from elastoplast.bounds.upper import UpperBound, conservative_discretization, smallest_upper_bound
from elastoplast.fem.discretize import Discretization
from elastoplast.solvers.path import WARM_STARTS, run_from
from elastoplast.solvers.registry import METHODS, get_method, given_options, solve


#: the KKT tolerance of the P1 solutions the local lower bound is built from: its contact
#: layer needs the nodal balance to 1e-13 of the contact force (``contact_layer.LAYER_TOL``),
#: about a tenth of the solution's KKT residual. Measured on the cylinder (576 triangles):
#: newton at tol 1e-8 (residual 1.2e-10) and a warm start at 1e-10 refused, at 1e-12
#: (3.7e-15) certified; conic polishes to 5.8e-15 at any tol, uzawa at 1e-12 reaches 7.7e-13.
#: 1e-13 (the tightest tolerance a method takes) rather than 1e-12: the equilibration inherits
#: the solution's nodal imbalance, which the ring repair must then remove, pass after pass.
#: Default 3D problem at 98,304 tetrahedra, newton: 9 iterations either way (5.1 s / 4.8 s),
#: KKT 7.4e-14 / 7.1e-15, element imbalance after the equilibration 2.6e-13 / 1.1e-14
LOCAL_SOLVE_TOL = 1e-13


def bracket_method(solution) -> str:
    """The method of the P1 solves at ``F -/+ delta``: the solution's own when it is a
    built-in method, else newton."""
    return solution.method if getattr(solution, "method", None) in METHODS else "newton"


def solve_at(disc: Discretization, force: float, method: str, start=None, tol: float | None = None, **options):
    """The P1 solution of ``disc`` at ``force`` by ``method`` (solver options as for
    :func:`~elastoplast.solvers.registry.solve`: an options object as ``options=`` or
    keywords; ``tol``: at most this KKT tolerance), from ``start`` (a solution of ``disc``,
    its contact forces scaled to ``force``) where the method takes a start
    (:data:`~elastoplast.solvers.path.WARM_STARTS`); cold again if that does not converge."""
    at = disc.with_force(force)
    m = get_method(method)
    values = dict(options)
    opts = given_options(method, values.pop("options", None), values)
    if tol is not None and opts.tol > tol:
        opts = replace(opts, tol=tol)
    opts = replace(opts, progress=False)  # within the caller's progress (the lower bounds')
    if start is None or m.name not in WARM_STARTS:
        return run_from(at, m, opts, None)
    start = replace(start, contact_force=np.asarray(start.contact_force) * (force / disc.force))
    sol = run_from(at, m, opts, start)
    return sol if sol.converged else run_from(at, m, opts, None)


def local_solution(disc: Discretization, solution, method: str | None = None, **options):
    """``solution`` if it is accurate enough for the local lower bound (its KKT residual at
    most :data:`LOCAL_SOLVE_TOL`), else the solution of ``disc`` solved again to that
    tolerance from it (:func:`solve_at`; ``method``: :func:`bracket_method` by default)."""
    if solution.converged and solution.kkt.worst <= LOCAL_SOLVE_TOL:
        return solution
    again = solve_at(disc, disc.force, method or bracket_method(solution), solution, LOCAL_SOLVE_TOL, **options)
    return again if again.kkt.worst <= solution.kkt.worst or not solution.converged else solution


def displacement_slope(disc: Discretization, method: str = "conic", step: float = 0.05, **options) -> float:
    """``dU/dF`` of the discrete problem by a central difference ``±step F``
    (used only to choose δ, so its accuracy does not matter for the bound)."""
    F = disc.force
    U = [solve(disc.with_force(F * (1 + s)), method, **options).U for s in (-step, step)]
    return float((U[1] - U[0]) / (2.0 * step * F))


def best_upper_bound(disc: Discretization, solution, method: str = "conic", conservative: bool = True,
                     **options) -> UpperBound:
    """:func:`smallest_upper_bound` of ``solution`` and, with ``conservative``, of the
    solution of :func:`conservative_discretization` solved by ``method`` (left out when
    that solve does not converge, or for a flat obstacle, which needs no allowance)."""
    other_sol = None
    safe = conservative_discretization(disc) if conservative else disc
    if conservative and not np.array_equal(safe.psi, disc.psi):  # a flat obstacle needs no allowance
        other_sol = solve(safe, method, **options)
        if not other_sol.converged:  # the problem's own solution's bound stands
            other_sol = None
    return smallest_upper_bound(disc, solution, other_sol)
