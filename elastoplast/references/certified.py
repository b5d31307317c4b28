"""Certified bounds of a problem from its solution: the energy bracket and the U bracket (docs/bounds.md).

:func:`certified_bounds` solves the problem where no solution is given, bounds it from
above and below (:mod:`elastoplast.bounds`) and brackets U through the lower bounds at
``F -/+ delta`` (:func:`u_bracket_of`; with the local lower bound, two more P1 solves,
:mod:`elastoplast.references.solves`). This layer sits above the bounds, which never run a
solve, and below the adaptive loop and the command line that use it."""

from __future__ import annotations

import math
import time
import warnings
from typing import Callable

import numpy as np

from elastoplast.bounds.bracket import (
    GAP_FLOOR,
    Bounds,
    BoundsReport,
    Progress,
    check_progress,
    choose_delta,
    combine,
    lower_bound,
    scaled_progress,
    u_secants,
)
from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_kind
from elastoplast.bounds.upper import upper_bound
from elastoplast.certificate.solution import check_solution
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization, check_hencky
from elastoplast.references.solves import LOCAL_SOLVE_TOL, best_upper_bound, bracket_method, local_solution, solve_at
from elastoplast.solvers.registry import solve


#: times the U bracket's delta above F is divided by 4 when the load there has no admissible field
BRACKET_RETRIES = 4


def certified_bounds(disc: Discretization, solution=None, method: str = "conic", conservative: bool = True,
                     lower_options=None, *, bracket: bool = True, progress: Progress | None = None,
                     **options) -> BoundsReport:
    """The energy bracket of ``disc`` and, with ``bracket``, the U bracket.

    The lower bound is :func:`lower_bound`'s (``lower_options.kind``: the global program,
    or the local field built from the P1 solution). U bracket (:func:`u_bracket`): only
    the lower bounds are needed at ``F -/+ delta`` (``U >= (lo(F - delta) - hi(F)) /
    delta``, ``U <= (hi(F) - lo(F + delta')) / delta'``): two more equilibrium-element
    programs and no P1 solve, or, with the local bound, two more P1 solves (``method``,
    warm-started from the solution at F, :func:`solve_at`) and their local bounds; delta
    is :func:`choose_delta` with the secant ``U / F`` for ``dU/dF`` (delta only sets how
    tight the bracket is, never whether it holds). The two inequalities hold for any
    delta each: with H = 0 and F + delta above the mesh's static limit load, ``delta'``
    is divided by 4 until the equilibrium element carries the load (at most
    :data:`BRACKET_RETRIES` times; else ``U_upper = inf``, and the bracket is not called
    certified). ``progress(fraction, what)``, when given, is called as the lower bounds
    advance (the local bound reports within itself).
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_hencky(disc, "the certified bounds")
    if solution is not None:
        check_solution(disc, solution, "solution", reads=("u",))
    lower_options = LowerBoundOptions.of(lower_options, "lower_options")
    check_progress(progress)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    sol = solve(disc, method, **options) if solution is None else solution
    upper = best_upper_bound(disc, sol, method, conservative, **options)
    t1 = time.perf_counter()
    local = lower_bound_kind(disc, lower_options) == "local"
    part = scaled_progress(progress, 0.0, 1.0 / 3 if bracket else 1.0)
    if local:  # the local field is built from a solution accurate to LOCAL_SOLVE_TOL
        if part is not None and not (sol.converged and sol.kkt.worst <= LOCAL_SOLVE_TOL):
            part(0.0, f"P1 solution to tol {LOCAL_SOLVE_TOL:g} for the local bound")
        sol = local_solution(disc, sol, method, **options)
    lower = lower_bound(disc, sol, lower_options, progress=part, upper=upper.Pi)
    t2 = time.perf_counter()
    timings.update(upper=t1 - t0, lower=t2 - t1)
    b = combine(upper, lower)
    if not bracket:
        return BoundsReport(bounds=b, upper=upper, lower=lower, timings=timings)
    U_lo, U_hi, delta, ok = u_bracket_of(disc, b, sol.U, lower_options, solution=sol, method=method,
                                         progress=scaled_progress(progress, 1.0 / 3, 1.0), **options)
    timings["bracket"] = time.perf_counter() - t2
    return BoundsReport(bounds=b, upper=upper, lower=lower, U_lower=U_lo, U_upper=U_hi, delta=delta, timings=timings,
                        bracket_certified=ok)


def energy_bounds(disc: Discretization, solution=None, method: str = "conic", conservative: bool = True,
                  lower_options=None, **options) -> Bounds:
    """``-J <= Pi* <= Pi`` on ``disc``: :func:`best_upper_bound` of ``solution``
    (solved by ``method`` when not given) and the lower bound of :func:`lower_bound`
    (``lower_options.kind``)."""
    return certified_bounds(disc, solution, method, conservative, lower_options, bracket=False, **options).bounds


def bounds_at(disc: Discretization, **kwargs) -> Callable[[float], tuple[float, float]]:
    """``F -> (lo, hi)`` by :func:`energy_bounds` on ``disc`` at load F (for :func:`u_bracket`)."""

    def run(force: float) -> tuple[float, float]:
        b = energy_bounds(disc.with_force(force), **kwargs)
        return b.energy_lower, b.energy_upper

    return run


def u_bracket_of(disc: Discretization, b: Bounds, U_h: float, lower_options=None, *, solution=None,
                 method: str | None = None, progress: Progress | None = None,
                 **options) -> tuple[float, float, tuple[float, float], bool]:
    """``(U_lower, U_upper, (delta, delta'), certified)``: the U bracket of :func:`u_bracket` from
    the energy bracket ``b`` at F and two more lower bounds (:func:`lower_bound`), at ``F -
    delta`` and ``F + delta'``; see :func:`certified_bounds` for the choice of delta and the
    shrinking of ``delta'``. The global program needs no P1 solve; the local bound
    (``lower_options.kind``) needs ``solution``, the P1 solution at F, from which the
    solutions at ``F -/+ delta`` are computed by ``method`` (default: the solution's own
    where it is a built-in method, else newton) with the solver ``options``."""

    lower_options = LowerBoundOptions.of(lower_options, "lower_options")
    check_progress(progress)
    F = disc.force
    # the gap used to choose delta never counts as less than the round-off of the bounds
    # themselves, so that (round-off of J) / delta stays far below the bracket's width
    gap = max(b.energy_gap, GAP_FLOOR * abs(b.energy_upper))
    delta = choose_delta(F, gap, U_h / F if U_h > 0 else 0.0)
    local = lower_bound_kind(disc, lower_options) == "local"
    if local:
        if solution is None:
            raise InputError("solution", "the U bracket with the local lower bound needs the P1 solution at F (the "
                                         "start of the solves at F -/+ delta), or the global program (kind 'global')")
        check_solution(disc, solution, "solution", reads=("u", "sigma", "contact_force"))
        method = method or bracket_method(solution)

    def bound_at(force: float, part: int):
        """The lower bound at ``force`` (its share ``part`` of ``progress``)."""
        report = scaled_progress(progress, part / 2, (part + 1) / 2)
        if not local:
            return lower_bound(disc.with_force(force), None, lower_options, progress=report)
        if report is not None:
            report(0.0, f"P1 solve at F = {force:.6g}")
        sol = solve_at(disc, force, method, solution, LOCAL_SOLVE_TOL, **options)
        at = disc.with_force(force)
        try:  # the solution's own upper bound there measures the gap the descent's gains are compared with
            return lower_bound(at, sol, lower_options, progress=report, upper=upper_bound(at, sol).Pi)
        except InputError as exc:  # the local field could not be built from this solution: no bracket
            raise InputError("mesh", f"the local lower bound at F = {force:.6g} (P1 solution: "
                                     f"{sol.status.value}, KKT residual {sol.kkt.worst:.1e}): {exc}") from None

    try:
        minus = bound_at(F - delta, 0)
    except InputError as exc:  # memory taken since the first program was checked: no bracket, said so
        if exc.field != "mesh":
            raise
        warnings.warn(f"no U bracket: {exc.message}")
        return math.nan, math.nan, (delta, delta), False
    # with H = 0, F + delta may lie above the mesh's static limit load (no admissible
    # field there): each side's secant holds for its own delta, so shrink that one
    plus, delta_plus = None, delta
    for _ in range(BRACKET_RETRIES):
        try:
            plus = bound_at(F + delta_plus, 1)
            break
        except InputError as exc:
            if exc.field == "mesh":
                warnings.warn(f"no U bracket: {exc.message}")
                return math.nan, math.nan, (delta, delta_plus), False
            if exc.field != "load.force":
                raise
            delta_plus /= 4.0
    plus_lower = plus.lower if plus is not None else -math.inf
    with np.errstate(all="ignore"):
        U_lo, U_hi = u_secants(minus.lower, b.energy_upper, plus_lower, delta, delta_plus)
    # the secants hold for valid bounds, so they are in order; their round-off is the bounds' own over delta
    energies = max(abs(minus.lower), abs(b.energy_upper), abs(plus_lower))
    ordered = math.isfinite(U_lo) and math.isfinite(U_hi) and (
        U_lo <= U_hi + GAP_FLOOR * energies * (1.0 / delta + 1.0 / delta_plus))
    if plus is not None and not ordered:
        warnings.warn(f"the U bracket is inverted or not finite (U_lower {U_lo:.6g} > U_upper {U_hi:.6g}): not "
                      "certified")
    certified = minus.certified and plus is not None and plus.certified and ordered
    return U_lo, U_hi, (delta, delta_plus), certified
