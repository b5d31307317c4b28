"""Adaptive refinement driven by the certified gap.

The gap between the upper bound Π(v, V) of the P1 solution and the lower bound
−J (docs/bounds.md) is a sum of element and
contact-facet terms, each ≥ 0: a proof in total and an error indicator in its
parts. The loop

    solve (2.1) → bound (lower, upper, local gaps) → mark (Dörfler, θ) → refine

runs until the relative gap ``(upper − lower) / |upper|`` is at most ``rtol``, or
a budget is spent: ``max_iter`` meshes, ``max_elements`` (and the lower bound's
own limits, :func:`~elastoplast.adapt.budget.lower_bound_budget`), or ``time_limit``.

The lower bound of each mesh is :func:`~elastoplast.bounds.bracket.lower_bound`'s, of the
kind ``options.lower`` asks for: by default (``"auto"``) the global program (the optimum
of the equilibrium element) on meshes up to
:data:`~elastoplast.bounds.lower.AUTO_GLOBAL_MAX_ELEMENTS` (the program's size limit: 100,000
triangles, 25,000 tetrahedra), the local field built from the P1 solution above, whose cost grows like the
solve's; the global program's size limit
(:data:`~elastoplast.bounds.lower.LOWER_BOUND_MAX_ELEMENTS`, 25,000 tetrahedra) and memory
model then no longer stop the loop. Where the local bound is used, the P1 solves are
certified to :data:`~elastoplast.bounds.bracket.LOCAL_SOLVE_TOL` (its contact layer needs
the nodal balance to round-off). Marking uses the element gaps, each contact facet's gap added
to the element it bounds (:func:`~elastoplast.bounds.upper.element_indicators`);
refinement is conforming bisection (:func:`~elastoplast.mesh.refinement.refine`),
which keeps the facet groups, so the contact zone and the symmetry planes stay
exact and every mesh is nested in the last.

Budgets are planned for, not found out by overrunning them: when the mesh
Dörfler's θ asks for would exceed the element budget, or would take longer than
the time left (:func:`predicted_seconds`: the cost of the last meshes
extrapolated as a power of the number of elements, with the final U bracket),
θ is lowered (by bisection, marking a subset, since the marking is monotone) to
the largest value whose mesh fits; the loop stops when no mesh with at least
``MIN_GROWTH`` times the elements fits. A θ whose mesh would grow by less than
``min_growth`` is first raised (:func:`~elastoplast.adapt.budget.raised_theta`): every
mesh costs a lower bound, and small steps spend the budget on many of them. The time budget rests on a prediction
and is overrun by its error: measured on the 3D quarter sphere (Clarabel, commit 91d17b4), 669 s for a
600 s budget (the lower bound at F took the predicted 159 s, the two bracket
programs 1.2 times that each on a loaded machine).

Solves are warm-started (``warm_start``, Newton only): Newton starts from the
previous mesh's solution interpolated onto the new nodes
(:func:`~elastoplast.mesh.refinement.prolong_p1`), for the problem and for its
conservative variant (:func:`~elastoplast.bounds.upper.conservative_discretization`,
whose solution usually gives the smaller upper bound). The U bracket
(:func:`~elastoplast.bounds.bracket.u_bracket_of`) costs two more lower bounds, at
``F ∓ δ`` (with the local bound, each after a P1 solve warm-started from the solution at
F): by default (``bracket = "final"``) it is computed on the last mesh
only, whatever stopped the loop (the time budget reserves for it), unless what is left of
the time limit is less than its predicted cost (:func:`~elastoplast.adapt.budget.bracket_seconds`:
twice the last lower bound's time, plus the solves for the local bound: the
first mesh, always bounded, can overrun a small budget); then its two lower bounds at
``F ∓ δ`` are taken on the mesh before, if they fit (:func:`bracket_from`). The run's
energy bracket is the best certified lower and upper bound over all its meshes
(:func:`~elastoplast.adapt.records.run_bracket`); the loop stops on it too. For
comparison, :func:`uniform` runs the same pipeline refining every element.

Measured (benchmarks/adapt/REPORT.md): the lower-bound program is most of the
cost of a step (the P1 solves about 5 % in 2D, 1 % in 3D), so a U bracket at
every step nearly triples the loop's time (its two programs took 1.97 times the
one at F in 2D), and warm starts save Newton iterations (65 instead of 110 over
seven meshes of the 2D cylinder, the problem and its conservative variant) but
little of the total: 1.2 s of 37.6 s of lower bounds (benchmarks/adapt/warm.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from elastoplast.adapt.budget import (
    MIN_GROWTH,
    affordable_elements,
    bracket_seconds,
    has_local_bound,
    lower_bound_budget,
    next_mesh,
)
from elastoplast.adapt.records import AdaptOptions, AdaptResult, Step, run_bracket
from elastoplast.bounds.bracket import Bounds, element_indicators
from elastoplast.bounds.upper import conservative_discretization
from elastoplast.certificate.solution import Solution
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization, discretize
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.refinement import BisectionState, prolong_p1
from elastoplast.problem.definition import Problem

# ----------------------------------------------------------------------------
# one mesh: solve, bound, bracket
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Bounded:
    """What bounding one mesh produced: the row, and what the next mesh starts from."""

    row: Step
    disc: Discretization
    solution: Solution
    conservative: Solution | None
    bounds: Bounds


def _solve(disc: Discretization, options: AdaptOptions, start: Solution | None, required: bool = True,
           accept: float | None = None) -> Solution | None:
    """The P1 solution by ``options.method``; Newton from ``start`` when given (and
    from zero again if that fails). Not converged (nor, with ``accept``, certified to that
    looser tolerance: the user's, when ``options.tol`` is the local bound's tighter one,
    which round-off can keep out of reach): an ``InputError`` when ``required``, else None."""
    from elastoplast.solvers.registry import check_solvable, method_options, solve

    values = {"tol": options.tol} if options.method != "conic" else {}
    sol = None
    if start is not None and options.method == "newton":
        from elastoplast.solvers.newton import solve_newton

        opts = method_options("newton", values)
        check_solvable(disc, "newton", opts)
        sol = solve_newton(disc, opts, warm_start=start)
    if sol is None or not sol.converged:
        sol = solve(disc, options.method, **values)
    if sol.converged or (accept is not None and sol.kkt.worst <= accept):
        return sol
    if required:
        raise InputError("adapt", f"the P1 solution on a mesh of {disc.n_elements} elements did not converge: "
                                  f"{sol.message}")
    return None


def _lower_options(options: AdaptOptions):
    from elastoplast.bounds.lower import LowerBoundOptions

    return LowerBoundOptions(max_elements=options.lower_max_elements, kind=options.lower, descent=options.lower_descent)


def _solve_tol(disc: Discretization, options: AdaptOptions) -> float:
    """The P1 tolerance on ``disc``: ``options.tol``, at most the local lower bound's
    (:data:`~elastoplast.bounds.bracket.LOCAL_SOLVE_TOL`) where that bound is used."""
    from elastoplast.references.solves import LOCAL_SOLVE_TOL
    from elastoplast.bounds.lower import lower_bound_kind

    local = lower_bound_kind(disc, _lower_options(options)) == "local"
    return min(options.tol, LOCAL_SOLVE_TOL) if local else options.tol


def _bound(problem: Problem, options: AdaptOptions, step: int, start: tuple[Solution, Solution | None] | None,
           bracket: bool) -> _Bounded:
    """Solve and bound one mesh (the upper bound of :func:`~elastoplast.bounds.upper.best_upper_bound`
    with warm-started solves, the lower bound, their local gaps)."""
    from elastoplast.bounds.bracket import combine, lower_bound, lower_kind
    from elastoplast.bounds.upper import smallest_upper_bound

    t0 = time.perf_counter()
    disc = discretize(problem)
    tol = _solve_tol(disc, options)
    solve_options = replace(options, tol=tol)
    sol = _solve(disc, solve_options, None if start is None else start[0], accept=options.tol)
    cons = None
    cdisc = conservative_discretization(disc)
    if not np.array_equal(cdisc.psi, disc.psi):  # a flat obstacle needs no allowance: nothing to solve again
        # only a candidate: if its solve fails, the problem's own solution bounds alone
        cons = _solve(cdisc, solve_options, None if start is None else start[1], required=False, accept=options.tol)
    upper = smallest_upper_bound(disc, sol, cons)  # as bounds.best_upper_bound, with warm-started solves
    t1 = time.perf_counter()
    lower_options = _lower_options(options)
    if tol < options.tol:  # the local bound: from a solution to its tolerance (conic's polish may fall short)
        from elastoplast.references.solves import local_solution

        sol = local_solution(disc, sol, options.method)
    lower = lower_bound(disc, sol, lower_options, upper=upper.Pi)
    t2 = time.perf_counter()
    b = combine(upper, lower)
    row = Step(step=step, n_elements=disc.n_elements, n_nodes=disc.mesh.n_nodes, energy_lower=b.energy_lower,
               energy_upper=b.energy_upper, gap_rel=b.energy_gap_rel, certified=b.bounds_certified, U=sol.U,
               U_lower=math.nan, U_upper=math.nan, seconds=t2 - t0, solve_seconds=t1 - t0, lower_seconds=t2 - t1,
               iterations=sol.iterations, lower=lower_kind(lower))
    done = _Bounded(row=row, disc=disc, solution=sol, conservative=cons, bounds=b)
    return with_bracket(done, options) if bracket else done


def with_bracket(done: _Bounded, options: AdaptOptions, upper: float = math.inf) -> _Bounded:
    """``done`` with its U bracket (:func:`~elastoplast.bounds.bracket.u_bracket_of`: two more
    lower bounds, at ``F ∓ δ``, as the ``bounds`` command does: no P1 solve for the global
    program, two warm-started ones by ``options.method`` for the local bound). ``upper``: an
    upper bound of ``Pi*(F)`` from another mesh of the run, used where it is smaller."""
    t0 = time.perf_counter()
    b = replace(done.bounds, energy_upper=min(done.bounds.energy_upper, upper))
    return _bracketed(done, done.disc, done.solution, b, options, None, t0)


@dataclass(frozen=True)
class _Earlier:
    """What an earlier mesh leaves for a U bracket on it. Its discretisation is rebuilt when
    needed, so that it is not held while the last mesh's own bracket is computed."""

    row: Step
    problem: Problem
    solution: Solution
    bounds: Bounds


def bracket_from(done: _Bounded, earlier: _Earlier, options: AdaptOptions, upper: float = math.inf) -> _Bounded:
    """``done`` with a U bracket whose two lower bounds at ``F ∓ δ`` are bounded on an earlier
    mesh, and whose upper bound at F is the smallest of the two meshes' and ``upper`` (each
    bounds the same ``Pi*(F)``, so the secants of :func:`~elastoplast.bounds.bracket.u_secants`
    hold with any mix). δ is chosen for the earlier mesh's lower bound against that upper bound.
    A bracket refused there (the memory taken since) leaves ``done`` as it was; the caller says so."""
    t0 = time.perf_counter()
    b = earlier.bounds
    own = b.energy_upper if earlier.row.certified else math.inf  # only a certified upper bound is a bound
    b = replace(b, energy_upper=min(own, done.bounds.energy_upper, upper))
    bracketed = _bracketed(done, discretize(earlier.problem), earlier.solution, b, options, earlier.row.step, t0)
    return done if math.isnan(bracketed.row.U_lower) or math.isnan(bracketed.row.U_upper) else bracketed


def _bracketed(done: _Bounded, disc: Discretization, solution: Solution, b: Bounds, options: AdaptOptions,
               step: int | None, t0: float) -> _Bounded:
    """``done`` with the U bracket of the energy bracket ``b`` at F and two more lower bounds on
    ``disc`` (``step``: the step of that mesh when it is an earlier one), timed from ``t0``."""
    from elastoplast.references.certified import u_bracket_of

    lo, hi, _, certified = u_bracket_of(disc, b, solution.U, _lower_options(options), solution=solution,
                                        method=options.method)
    seconds = time.perf_counter() - t0
    row = replace(done.row, U_lower=lo, U_upper=hi, certified=done.row.certified and certified,
                  bracket_seconds=seconds, seconds=done.row.seconds + seconds, bracket_step=step)
    return replace(done, row=row)


# ----------------------------------------------------------------------------
# the loop
# ----------------------------------------------------------------------------


def adapt(problem: Problem, options: AdaptOptions = AdaptOptions(),
          report: Callable[[Step], None] | None = None) -> AdaptResult:
    """Refine where the certified gap is, until ``rtol`` or a budget; see the module docstring.

    ``report`` is called with each :class:`Step` as it is done (the command
    line prints it). Perfect plasticity (H = 0) is refused: local bisection breaks
    the crossed pattern, the only 2D pattern whose P1 elements do not lock, so the
    second mesh could not be solved (and P1 tetrahedra lock anyway).
    """
    check_adaptable(problem)
    options = AdaptOptions.of(options)
    check_lower_available(problem, options)
    return _loop(problem, options, report, adaptive=True)


def check_adaptable(problem: Problem) -> None:
    """Refuse what :func:`adapt` cannot run on, before any work: not a Problem, or H = 0."""
    expect(problem, Problem, "problem", "ep.problem_from_dict(data) or ep.load_problem(path)")
    if problem.material.hardening == 0:
        raise InputError("material.hardening", "adaptive refinement needs hardening > 0: bisection breaks the "
                                               "crossed pattern, and with H = 0 P1 meshes that are not crossed lock; "
                                               "'elastoplast limit' brackets the limit load")


def check_lower_available(problem: Problem, options: AdaptOptions) -> None:
    """Refuse the local lower bound on an axisymmetric model, before any work (the global
    program is the one lower bound there so far; ``"auto"`` chooses it)."""
    if problem.axisymmetric and options.lower == "local":
        raise InputError("lower", "the local lower bound is not available for axisymmetric models yet: use the "
                                  "global program ('global', or 'auto', which chooses it there)")


def uniform(problem: Problem, options: AdaptOptions = AdaptOptions(), max_elements: int | None = None,
            report: Callable[[Step], None] | None = None) -> AdaptResult:
    """The same pipeline refining every element (the comparison of the issue),
    up to ``max_elements`` (default: the options'), without U brackets."""
    expect(problem, Problem, "problem", "ep.problem_from_dict(data) or ep.load_problem(path)")
    options = AdaptOptions.of(options)
    check_lower_available(problem, options)
    opts = replace(options, max_elements=max_elements or options.max_elements, bracket="never")
    return _loop(problem, opts, report, adaptive=False)


#: the fields of the lower bound's refusals that end a run at its last mesh instead of failing it:
#: the memory available ("mesh"), and the local bound's contact layer ("boundary.contact": the
#: P1 solution's nodal balance next to Γ0 off by more than its round-off tolerance)
REFUSALS = ("mesh", "boundary.contact")


def _loop(problem: Problem, options: AdaptOptions, report, adaptive: bool) -> AdaptResult:
    t_start = time.perf_counter()
    mesh, state, start = problem.mesh, None, None
    steps: list[Step] = []
    meshes: list[Mesh] = []
    lower_name, lower_limit = lower_bound_budget(problem.dim, options, has_local_bound(problem))
    if mesh.n_elements > lower_limit:  # before any work (the next meshes are planned under it)
        raise InputError("mesh", f"{mesh.n_elements:,} elements: above {lower_name} ({lower_limit:,} elements for "
                                 "its lower bounds in a row); start from a coarser mesh")
    final_bracket = options.bracket == "final"
    earlier = None  # the last mesh before this one, for a U bracket there when this one's does not fit
    reason = f"max_iter = {options.max_iter} meshes solved"
    for k in range(options.max_iter):
        t0 = time.perf_counter()
        try:
            bounded = _bound(replace(problem, mesh=mesh), options, k, start, bracket=options.bracket == "every")
        except InputError as exc:  # memory taken by others since the plan, or the local bound's
            # refusal of a P1 solution whose balance next to Γ0 it cannot repair: keep what was done
            if exc.field not in REFUSALS or not steps:
                raise
            reason = (f"the lower bound refused the next mesh ({exc.field}: {exc.message}); the run ends at the "
                      "previous mesh, without its U bracket")
            break
        done = bounded
        meshes.append(mesh)
        row = done.row
        stop = None
        elapsed = time.perf_counter() - t_start
        run = run_bracket(steps + [row])
        if run.tighter_than(row.gap_rel) and run.gap_rel <= options.rtol:
            stop = f"relative gap {run.gap_rel:.3e} <= rtol {options.rtol:g} ({run.line()})"
        elif row.gap_rel <= options.rtol:
            stop = f"relative gap {row.gap_rel:.3e} <= rtol {options.rtol:g}"
        elif k == options.max_iter - 1:
            stop = reason
        elif options.time_limit is not None and elapsed >= options.time_limit:
            stop = f"time_limit {options.time_limit:g} s reached"
        if stop is None:
            eta = element_indicators(done.disc, done.bounds)
            budgets = {"max_elements": options.max_elements, lower_name: lower_limit}
            if options.time_limit is not None:
                left = options.time_limit - elapsed
                budgets["time_limit"] = affordable_elements(steps + [row], left, options.bracket != "never")
            allowed = min(budgets.values())
            nxt, wanted = next_mesh(mesh, state, eta, options.theta, allowed, adaptive, options.min_growth)
            if nxt is None:
                name = min(budgets, key=budgets.get)
                stop = f"{name}: the next mesh would have {wanted:,} elements"
                if name == "time_limit":
                    stop += (f", {options.time_limit - elapsed:.0f} s left afford about {allowed:,} (predicted from "
                             "the steps so far)")
                else:
                    stop += f" > {allowed:,}"
                if adaptive:
                    stop += f", and no smaller θ gives {MIN_GROWTH:g}x the {mesh.n_elements:,} elements within it"
        if stop is not None:
            best_upper = run.upper if run.certified else math.inf
            # the bracket is two more lower bounds, each about as long as this mesh's: not past the limit
            left = math.inf if options.time_limit is None else options.time_limit - (time.perf_counter() - t_start)
            if final_bracket and math.isnan(row.U_lower) and bracket_seconds(row) > left:
                if earlier is not None and bracket_seconds(earlier.row) <= left:
                    stop += (f"; this mesh's U bracket would take about {bracket_seconds(row):.0f} s, "
                             f"{left:.0f} s left: its lower bounds at F ∓ δ are those of step {earlier.row.step} "
                             f"({earlier.row.n_elements:,} elements)")
                    done = bracket_from(done, earlier, options, best_upper)
                    if math.isnan(done.row.U_lower):
                        stop += ", which could not be bounded: no U bracket"
                else:
                    stop += (f"; no U bracket: the time limit is spent" if left <= 0 else
                             f"; no U bracket: it would take about {bracket_seconds(row):.0f} s, {left:.0f} s "
                             "left")
            elif final_bracket and math.isnan(row.U_lower):
                done = with_bracket(done, options, best_upper)
            row = replace(done.row, seconds=time.perf_counter() - t0)
            steps.append(row)
            if report is not None:
                report(row)
            reason = stop
            break
        new_mesh, new_state, marked, theta = nxt
        row = replace(row, marked=int(marked.sum()), theta=theta, seconds=time.perf_counter() - t0)
        steps.append(row)
        if report is not None:
            report(row)
        if final_bracket:
            earlier = _Earlier(row=row, problem=done.disc.problem, solution=done.solution, bounds=done.bounds)
        if options.warm_start:
            start = (_prolonged(done.solution, new_state),
                     None if done.conservative is None else _prolonged(done.conservative, new_state))
        mesh, state = new_mesh, new_state
    return AdaptResult(steps=tuple(steps), meshes=tuple(meshes), disc=done.disc, solution=done.solution,
                       bounds=done.bounds, reason=reason)


def _prolonged(sol: Solution, state: BisectionState) -> Solution:
    """A start for the refined mesh: the solution's displacements interpolated onto its
    nodes (only ``u`` and ``U`` are read by Newton's warm start)."""
    return replace(sol, u=prolong_p1(state, sol.u))
