"""Adaptive refinement driven by the certified gap (issue 11).

The gap between the upper bound Π(v, V) of the P1 solution and the lower bound
−J of the equilibrium element (docs/bounds.md) is a sum of element and
contact-facet terms, each ≥ 0: a proof in total and an error indicator in its
parts. The loop

    solve (2.1) → bound (lower, upper, local gaps) → mark (Dörfler, θ) → refine

runs until the relative gap ``(upper − lower) / |upper|`` is at most ``rtol``, or
a budget is spent: ``max_iter`` meshes, ``max_elements`` (and the lower bound's
own size limit, :data:`~elastoplast.bounds.lower.LOWER_BOUND_MAX_ELEMENTS`), or
``time_limit``. Marking uses the element gaps, each contact facet's gap added
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
``MIN_GROWTH`` times the elements fits. The time budget rests on a prediction
and is overrun by its error: measured on the 3D quarter sphere (Clarabel, commit 91d17b4), 669 s for a
600 s budget (the lower bound at F took the predicted 159 s, the two bracket
programs 1.2 times that each on a loaded machine).

Solves are warm-started (``warm_start``, Newton only): Newton starts from the
previous mesh's solution interpolated onto the new nodes
(:func:`~elastoplast.mesh.refinement.prolong_p1`), for the problem and for its
conservative variant (:func:`~elastoplast.bounds.upper.conservative_discretization`,
whose solution usually gives the smaller upper bound). The U bracket
(:func:`~elastoplast.bounds.upper.u_bracket`) costs two more lower-bound programs, at
``F ∓ δ``: by default (``bracket = "final"``) it is computed on the last mesh
only, whatever stopped the loop (the time budget reserves for it), unless what is left of
the time limit is less than its predicted cost (twice the last lower bound's time: the
first mesh, always bounded, can overrun a small budget). For
comparison, :func:`uniform` runs the same pipeline refining every element.

Measured (benchmarks/adapt/REPORT.md): the lower-bound program is most of the
cost of a step (the P1 solves about 5 % in 2D, 1 % in 3D), so a U bracket at
every step nearly triples the loop's time (its two programs took 1.97 times the
one at F in 2D), and warm starts save Newton iterations (25 instead of 45 over
six meshes in 2D) but little of the total (benchmarks/adapt/warm.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from elastoplast.bounds.bracket import Bounds, element_indicators
from elastoplast.bounds.upper import conservative_discretization
from elastoplast.fem.discretize import Discretization, discretize
from elastoplast.errors import InputError, expect
from elastoplast.mesh.base import Mesh
from elastoplast.problem.options import SolverOptions, option
from elastoplast.problem.definition import Problem
from elastoplast.mesh.refinement import BisectionState, dorfler_mark, prolong_p1, refine
from elastoplast.certificate.solution import Solution

#: a refinement step must at least multiply the elements by this, else the loop stops
#: (a step costs a lower-bound program: one that adds a handful of elements is not worth it)
MIN_GROWTH = 1.25
#: bisection steps on θ when the marked mesh does not fit a budget
FIT_STEPS = 10


@dataclass(frozen=True)
class AdaptOptions(SolverOptions):
    """Settings of :func:`adapt` (declared and checked like every solver's options).

    ``tol`` here is ``rtol``'s companion for the P1 solves: the KKT tolerance
    each mesh's discrete solution is certified to (the bounds need the discrete
    solution only as a candidate, but an accurate one keeps the upper bound
    tight). ``max_iter`` bounds the number of meshes (``max_steps``).
    ``lower_max_elements``: the lower bound's size limit (None: its default,
    :data:`~elastoplast.bounds.lower.LOWER_BOUND_MAX_ELEMENTS`); the loop never
    builds a mesh above it or above ``max_elements``.
    """

    max_iter: int = option(30, int, "most meshes solved (adaptive steps)", lo=1, hi=200)
    tol: float = option(1e-8, float, "KKT tolerance of each mesh's P1 solution", lo=1e-13, hi=1e-4)
    rtol: float = option(1e-3, float, "target relative energy gap (upper - lower) / |upper|", lo=1e-8, hi=1.0,
                         lo_open=True)
    theta: float = option(0.5, float, "Dörfler parameter: mark the smallest set carrying this share of the gap",
                          lo=0.0, hi=1.0, lo_open=True)
    max_elements: int = option(2_000_000, int, "stop before a mesh with more elements", lo=1, hi=100_000_000)
    method: str = option("newton", str, "the P1 solver", choices=("conic", "newton", "uzawa", "uzawa-fast"))
    bracket: str = option("final", str, "U bracket on the final mesh only, at every step, or never",
                          choices=("every", "final", "never"))
    compare_uniform: bool = option(True, bool, "also run uniform refinement for the plot (command only)")
    warm_start: bool = option(True, bool, "Newton from the previous mesh's solution, interpolated", persist=False)
    lower_max_elements: int | None = option(None, int, "the lower bound's size limit (none: its default)", lo=1,
                                            hi=100_000_000, none=True)


@dataclass(frozen=True)
class Step:
    """One mesh of the sequence: its size, bounds, U bracket and cost.

    ``seconds`` is the whole step (solves, bounds, bracket, marking and
    refinement); ``solve_seconds`` the P1 solves (the problem and its
    conservative variant), ``lower_seconds`` the lower-bound program at F,
    ``bracket_seconds`` the two at ``F ∓ δ``; ``iterations`` the solver
    iterations of the P1 solve of the problem; ``theta`` the Dörfler parameter
    the marking used (lowered to fit a budget), ``marked`` the elements it marked.
    """

    step: int
    n_elements: int
    n_nodes: int
    energy_lower: float
    energy_upper: float
    gap_rel: float
    certified: bool
    U: float
    U_lower: float
    U_upper: float
    seconds: float
    marked: int = 0
    solve_seconds: float = 0.0
    lower_seconds: float = 0.0
    bracket_seconds: float = 0.0
    iterations: int = 0
    theta: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def line(self) -> str:
        bracket = "" if math.isnan(self.U_lower) else f"  U in [{self.U_lower:.6g}, {self.U_upper:.6g}]"
        flag = "" if self.certified else "  (NOT certified)"
        return (f"step {self.step:2d}  {self.n_elements:9,d} elements  lower {self.energy_lower:.8g}  "
                f"upper {self.energy_upper:.8g}  gap {self.gap_rel:.3e}{bracket}  {self.seconds:.1f} s{flag}")


@dataclass(frozen=True)
class AdaptResult:
    """The sequence of meshes and the final answer: ``disc``, ``solution``,
    ``bounds`` (:class:`~elastoplast.bounds.upper.Bounds`) of the last mesh;
    ``meshes`` every mesh solved; ``reason`` why the loop stopped."""

    steps: tuple[Step, ...]
    meshes: tuple[Mesh, ...] = field(repr=False)
    disc: Discretization = field(repr=False)
    solution: Solution = field(repr=False)
    bounds: Any = field(repr=False)
    reason: str = ""

    @property
    def final(self) -> Step:
        return self.steps[-1]


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


def _solve(disc: Discretization, options: AdaptOptions, start: Solution | None, required: bool = True) -> Solution | None:
    """The P1 solution by ``options.method``; Newton from ``start`` when given (and
    from zero again if that fails). Not converged: an ``InputError`` when
    ``required``, else None."""
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
    if sol.converged:
        return sol
    if required:
        raise InputError("adapt", f"the P1 solution on a mesh of {disc.n_elements} elements did not converge: "
                                  f"{sol.message}")
    return None


def _lower_options(options: AdaptOptions):
    from elastoplast.bounds.lower import LowerBoundOptions

    return LowerBoundOptions(max_elements=options.lower_max_elements)


def lower_bound_budget(dim: int, options: AdaptOptions) -> tuple[str, int]:
    """``(what limits it, elements)``: the largest mesh the lower bound accepts with
    these options and whose programs, run one after another in this process, fit in
    the memory available (:func:`~elastoplast.bounds.lower.lower_bound_fits`)."""
    from elastoplast.bounds.lower import LOWER_BOUND_MAX_ELEMENTS, lower_bound_fits

    largest = options.lower_max_elements or LOWER_BOUND_MAX_ELEMENTS[dim]
    fits = lower_bound_fits(dim)
    if fits is not None and fits < largest:
        return "the memory available to the lower bound", max(1, fits)
    return "the lower bound's size limit", largest


def lower_bound_limit(dim: int, options: AdaptOptions) -> int:
    """The elements of :func:`lower_bound_budget`."""
    return lower_bound_budget(dim, options)[1]


def _bound(problem: Problem, options: AdaptOptions, step: int, start: tuple[Solution, Solution | None] | None,
           bracket: bool) -> _Bounded:
    """Solve and bound one mesh (the upper bound of :func:`~elastoplast.bounds.upper.best_upper_bound`
    with warm-started solves, the lower bound, their local gaps)."""
    from elastoplast.bounds.bracket import combine
    from elastoplast.bounds.upper import smallest_upper_bound
    from elastoplast.bounds.lower import solve_lower_bound

    t0 = time.perf_counter()
    disc = discretize(problem)
    sol = _solve(disc, options, None if start is None else start[0])
    cons = None
    cdisc = conservative_discretization(disc)
    if not np.array_equal(cdisc.psi, disc.psi):  # a flat obstacle needs no allowance: nothing to solve again
        # only a candidate: if its solve fails, the problem's own solution bounds alone
        cons = _solve(cdisc, options, None if start is None else start[1], required=False)
    upper = smallest_upper_bound(disc, sol, cons)  # as bounds.best_upper_bound, with warm-started solves
    t1 = time.perf_counter()
    lower = solve_lower_bound(disc, _lower_options(options))
    t2 = time.perf_counter()
    b = combine(upper, lower)
    row = Step(step=step, n_elements=disc.n_elements, n_nodes=disc.mesh.n_nodes, energy_lower=b.energy_lower,
               energy_upper=b.energy_upper, gap_rel=b.energy_gap_rel, certified=b.bounds_certified, U=sol.U,
               U_lower=math.nan, U_upper=math.nan, seconds=t2 - t0, solve_seconds=t1 - t0, lower_seconds=t2 - t1,
               iterations=sol.iterations)
    done = _Bounded(row=row, disc=disc, solution=sol, conservative=cons, bounds=b)
    return with_bracket(done, options) if bracket else done


def with_bracket(done: _Bounded, options: AdaptOptions) -> _Bounded:
    """``done`` with its U bracket (:func:`~elastoplast.bounds.upper.u_bracket_of`: two more
    lower bounds, at ``F ∓ δ``, and no P1 solve, as the ``bounds`` command does)."""
    from elastoplast.bounds.bracket import u_bracket_of

    t0 = time.perf_counter()
    disc, sol, b = done.disc, done.solution, done.bounds
    lo, hi, _, certified = u_bracket_of(disc, b, sol.U, _lower_options(options))
    seconds = time.perf_counter() - t0
    row = replace(done.row, U_lower=lo, U_upper=hi, certified=done.row.certified and certified,
                  bracket_seconds=seconds, seconds=done.row.seconds + seconds)
    return replace(done, row=row)


def bound_mesh(problem: Problem, options: AdaptOptions, *, bracket: bool, step: int = 0,
               t_start: float | None = None) -> tuple[Step, Discretization, Solution, Bounds]:
    """Solve and bound one mesh, cold: the :class:`Step` row and what it was computed from
    (``t_start``: count the row's seconds from there)."""
    done = _bound(problem, options, step, None, bracket)
    row = done.row if t_start is None else replace(done.row, seconds=time.perf_counter() - t_start)
    return row, done.disc, done.solution, done.bounds


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
    return _loop(problem, AdaptOptions.of(options), report, adaptive=True)


def check_adaptable(problem: Problem) -> None:
    """Refuse what :func:`adapt` cannot run on, before any work: not a Problem, or H = 0."""
    expect(problem, Problem, "problem", "ep.problem_from_dict(data) or ep.load_problem(path)")
    if problem.material.hardening == 0:
        raise InputError("material.hardening", "adaptive refinement needs hardening > 0: bisection breaks the "
                                               "crossed pattern, and with H = 0 P1 meshes that are not crossed lock; "
                                               "'elastoplast limit' brackets the limit load")


def uniform(problem: Problem, options: AdaptOptions = AdaptOptions(), max_elements: int | None = None,
            report: Callable[[Step], None] | None = None) -> AdaptResult:
    """The same pipeline refining every element (the comparison of the issue),
    up to ``max_elements`` (default: the options'), without U brackets."""
    expect(problem, Problem, "problem", "ep.problem_from_dict(data) or ep.load_problem(path)")
    options = AdaptOptions.of(options)
    opts = replace(options, max_elements=max_elements or options.max_elements, bracket="never")
    return _loop(problem, opts, report, adaptive=False)


def _cost_model(steps: list[Step], bracket: bool) -> tuple[int, float, float]:
    """``(N_last, cost_last, a)`` of :func:`predicted_seconds`."""
    last = steps[-1]
    n = np.array([s.n_elements for s in steps[-3:]], dtype=float)
    cost = np.array([s.solve_seconds + s.lower_seconds for s in steps[-3:]])
    a = 1.5
    if n.size >= 2 and n[-1] > n[0] and np.all(cost > 0):
        a = float(np.clip(np.polyfit(np.log(n), np.log(cost), 1)[0], 1.0, 2.5))
    return last.n_elements, last.solve_seconds + last.lower_seconds * (3.0 if bracket else 1.0), a


def predicted_seconds(steps: list[Step], n_elements: int, bracket: bool) -> float:
    """The predicted cost of bounding a mesh of ``n_elements`` (with its U bracket
    when ``bracket``: two more lower-bound programs), from the steps so far:
    ``cost(N) = cost_last (N / N_last)^a``, ``cost_last`` the last step's solves and
    lower bound(s), ``a`` the slope of log(solves + lower bound) in log(N) over the
    last three steps, kept in [1, 2.5] (the interior point's cost grows like
    N^1.3-1.5 in 3D, benchmarks/bounds/lower.md; a slope outside that range is
    timing noise), 1.5 after a single step."""
    n_last, cost, a = _cost_model(steps, bracket)
    return cost * (n_elements / n_last) ** a


def affordable_elements(steps: list[Step], seconds: float, bracket: bool) -> int:
    """The largest mesh whose :func:`predicted_seconds` is at most ``seconds``."""
    n_last, cost, a = _cost_model(steps, bracket)
    if seconds <= 0:
        return 0
    return int(n_last * (seconds / cost) ** (1.0 / a)) if cost > 0 else 2**62


def _next_mesh(mesh: Mesh, state: BisectionState | None, eta: np.ndarray, theta: float, allowed: int,
               adaptive: bool) -> tuple[tuple[Mesh, BisectionState, np.ndarray, float] | None, int]:
    """The refined mesh Dörfler's ``theta`` marks (every element when not
    ``adaptive``), or, when it has more than ``allowed`` elements, the one of the
    largest smaller θ that fits (the marked sets are nested in θ, hence so are the
    meshes) if it has at least ``MIN_GROWTH`` times the elements; else None.
    Returns ``((mesh, state, marked, θ) or None, elements of the mesh θ asks for)``."""
    marked = dorfler_mark(eta, theta) if adaptive else np.ones(eta.size, dtype=bool)
    new, st, _ = refine(mesh, marked, state)
    wanted = new.n_elements
    if wanted <= allowed:
        return (new, st, marked, theta if adaptive else math.nan), wanted
    if not adaptive:
        return None, wanted
    best, lo, hi = None, 0.0, theta
    for _ in range(FIT_STEPS):
        t = 0.5 * (lo + hi)
        m = dorfler_mark(eta, t)
        cand = refine(mesh, m, state)[:2]
        if cand[0].n_elements <= allowed:
            best, lo = (cand[0], cand[1], m, t), t
        else:
            hi = t
    if best is None or best[0].n_elements < MIN_GROWTH * mesh.n_elements:
        return None, wanted
    return best, wanted


def _loop(problem: Problem, options: AdaptOptions, report, adaptive: bool) -> AdaptResult:
    t_start = time.perf_counter()
    mesh, state, start = problem.mesh, None, None
    steps: list[Step] = []
    meshes: list[Mesh] = []
    lower_name, lower_limit = lower_bound_budget(problem.dim, options)
    if mesh.n_elements > lower_limit:  # before any work (the next meshes are planned under it)
        raise InputError("mesh", f"{mesh.n_elements:,} elements: above {lower_name} ({lower_limit:,} elements for "
                                 "its programs in a row); start from a coarser mesh")
    final_bracket = options.bracket == "final"
    reason = f"max_iter = {options.max_iter} meshes solved"
    for k in range(options.max_iter):
        t0 = time.perf_counter()
        try:
            bounded = _bound(replace(problem, mesh=mesh), options, k, start, bracket=options.bracket == "every")
        except InputError as exc:  # memory taken by others since the plan: keep what was done
            if exc.field != "mesh" or not steps:
                raise
            reason = (f"the lower bound refused the next mesh ({exc.message}); the run ends at the previous mesh, "
                      "without its U bracket")
            break
        done = bounded
        meshes.append(mesh)
        row = done.row
        stop = None
        elapsed = time.perf_counter() - t_start
        if row.gap_rel <= options.rtol:
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
            nxt, wanted = _next_mesh(mesh, state, eta, options.theta, allowed, adaptive)
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
            # the bracket is two more lower bounds, each about as long as this mesh's: not past the limit
            left = math.inf if options.time_limit is None else options.time_limit - (time.perf_counter() - t_start)
            if final_bracket and math.isnan(row.U_lower) and 2.0 * row.lower_seconds > left:
                stop += (f"; no U bracket: the time limit is spent" if left <= 0 else
                         f"; no U bracket: it would take about {2.0 * row.lower_seconds:.0f} s, {left:.0f} s left")
            elif final_bracket and math.isnan(row.U_lower):
                done = with_bracket(done, options)
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


def fitted_rate(steps: tuple[Step, ...] | list[Step], last: int | None = None) -> float:
    """The exponent p of ``gap_rel ~ elements^(-p)``, least squares over the steps
    (the ``last`` ones only when given; NaN with fewer than two)."""
    steps = list(steps)[-last:] if last else list(steps)
    n = np.array([s.n_elements for s in steps], dtype=float)
    g = np.array([s.gap_rel for s in steps], dtype=float)
    ok = (n > 0) & (g > 0) & np.isfinite(g)
    if ok.sum() < 2:
        return math.nan
    return float(-np.polyfit(np.log(n[ok]), np.log(g[ok]), 1)[0])


def elements_at_gap(steps: tuple[Step, ...] | list[Step], gap: float) -> float:
    """The number of elements at which the sequence reaches relative gap ``gap``:
    log-log interpolation between the first step at or below ``gap`` and the one
    before it (the first step's size if it is already there); NaN if never reached."""
    n = np.array([s.n_elements for s in steps], dtype=float)
    g = np.array([s.gap_rel for s in steps], dtype=float)
    below = np.flatnonzero(g <= gap)
    if below.size == 0:
        return math.nan
    i = int(below[0])
    if i == 0:
        return float(n[0])
    t = (np.log(g[i - 1]) - np.log(gap)) / (np.log(g[i - 1]) - np.log(g[i]))
    return float(np.exp(np.log(n[i - 1]) + t * (np.log(n[i]) - np.log(n[i - 1]))))


__all__ = ["AdaptOptions", "AdaptResult", "Step", "adapt", "affordable_elements", "bound_mesh", "draw_indicator",
           "elements_at_gap", "fitted_rate", "lower_bound_budget", "lower_bound_limit", "plot_gap_curves",
           "plot_indicator", "predicted_seconds", "run_adapt_command", "slice_polygons", "uniform", "with_bracket",
           "zoom_window"]


# ----------------------------------------------------------------------------
# pictures: the gap against the elements; the adapted mesh coloured by the indicator
# ----------------------------------------------------------------------------


def plot_gap_curves(ax, curves: dict[str, list[Step] | tuple[Step, ...]], last: int | None = None) -> None:
    """The relative gap against the number of elements (log-log), one curve per
    sequence of steps, labelled with its fitted exponent (:func:`fitted_rate`
    over the ``last`` steps when given)."""
    styles = ["o-", "s--", "^-", "v-", "D:", "x--"]
    for (name, steps), style in zip(curves.items(), styles * 4):
        if not steps:
            continue
        ax.loglog([s.n_elements for s in steps], [s.gap_rel for s in steps], style, ms=4,
                  label=f"{name} (p = {fitted_rate(steps, last):.2f})")
    ax.set_xlabel("elements")
    ax.set_ylabel("relative energy gap (upper − lower) / |upper|")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def plot_gaps(path, adaptive: AdaptResult, uniform_run: AdaptResult | None, title: str = "") -> None:
    """The relative gap against the number of elements, adaptive and uniform (log-log)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    curves = {"adaptive": adaptive.steps}
    if uniform_run is not None:
        curves["uniform"] = uniform_run.steps
    plot_gap_curves(ax, curves)
    ax.set_title(title)
    fig.savefig(path, dpi=120)


def _pair_key(i: np.ndarray, j: np.ndarray, n: int) -> np.ndarray:
    """One int64 per unordered pair of indices below ``n``."""
    lo, hi = np.minimum(i, j).astype(np.int64), np.maximum(i, j).astype(np.int64)
    return lo * np.int64(n) + hi


_TET_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])


def slice_polygons(mesh: Mesh, axis: int, value: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cut of a tetrahedral mesh by the plane ``x[axis] = value``.

    Returns ``(polygons (m, 4, 2), elements (m,), keys (m, 4))``: each cut
    tetrahedron's section (a triangle, its last vertex repeated, or a
    quadrilateral) in the plane's two other coordinates, in angular order; the
    tetrahedron's index; and for each vertex the mesh edge it lies on (one
    integer per edge, so that neighbours' sections share vertex keys exactly).
    A plane through mesh nodes (a symmetry plane, a layer of the grid) is moved
    by 1e-9 of the mesh size, into the mesh when it is a boundary plane, so that
    every section is a proper polygon; a face lying in the plane is drawn once (as
    the section of one of its tetrahedra), and tetrahedra touching the plane by an
    edge or a vertex only are left out.
    """
    p = mesh.points
    size = float(np.ptp(p, axis=0).max())
    lo, hi = float(p[:, axis].min()), float(p[:, axis].max())
    v = value + 1e-9 * size if value < hi - 1e-9 * size else hi - 1e-9 * size
    v = max(v, lo + 1e-9 * size)
    X = p[mesh.cells]
    dist = X[:, :, axis] - v
    exact = X[:, :, axis] - value
    on = np.abs(exact) <= 1e-12 * size
    # a tetrahedron with a face in the plane, or crossing it; not one touching it by an edge or a vertex only
    proper = (on.sum(axis=1) == 3) | ((exact < 0) & ~on).any(axis=1) & ((exact > 0) & ~on).any(axis=1)
    cut = np.flatnonzero((dist.min(axis=1) < 0) & (dist.max(axis=1) > 0) & proper)
    X, dist, cells = X[cut], dist[cut], mesh.cells[cut]
    a, b = _TET_EDGES[:, 0], _TET_EDGES[:, 1]
    da, db = dist[:, a], dist[:, b]
    cross = da * db < 0
    t = np.where(cross, da / np.where(cross, da - db, 1.0), 0.0)
    P = X[:, a] + t[..., None] * (X[:, b] - X[:, a])
    Q = P[:, :, [i for i in range(3) if i != axis]]
    keys = _pair_key(cells[:, a], cells[:, b], mesh.n_nodes)
    count = cross.sum(axis=1)
    centre = (Q * cross[..., None]).sum(axis=1) / count[:, None]
    angle = np.arctan2(Q[..., 1] - centre[:, None, 1], Q[..., 0] - centre[:, None, 0])
    order = np.argsort(np.where(cross, angle, np.inf), axis=1)[:, :4]
    Q = np.take_along_axis(Q, order[..., None], axis=1)
    keys = np.take_along_axis(keys, order, axis=1)
    tri = count == 3
    Q[tri, 3], keys[tri, 3] = Q[tri, 2], keys[tri, 2]
    return Q, cut, keys


def _outline(polygons: np.ndarray, keys: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The segments ``(s, 2, 2)`` between polygons ``inside`` and polygons outside:
    the edges (pairs of vertex keys) met twice in all polygons and once among
    those inside."""
    k = polygons.shape[1]
    n = int(keys.max(initial=0)) + 1
    pair = _pair_key(keys, np.roll(keys, -1, axis=1), n).ravel()
    seg = np.stack([polygons, np.roll(polygons, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    flag = np.repeat(inside, k)
    ok = (keys != np.roll(keys, -1, axis=1)).ravel()
    _, inv, count = np.unique(pair[ok], return_inverse=True, return_counts=True)
    count_in = np.bincount(inv, weights=flag[ok], minlength=count.size)
    sel = (count[inv] == 2) & (count_in[inv] == 1) & flag[ok]
    return seg[ok][sel]


def draw_indicator(ax, disc: Discretization, solution: Solution, eta: np.ndarray, *, axis: int | None = None,
                   value: float = 0.0, window: tuple[float, float, float, float] | None = None, edges: bool = True):
    """Draw the mesh coloured by the indicator ``eta`` (one value per element,
    logarithmic colours), the outline of the plastic zone (black) and the active
    contact (red line, the contact edge marked by triangles).

    2D: the triangles in the (x, y) plane. 3D: the section of the mesh by the
    plane ``x[axis] = value`` (:func:`slice_polygons`; e.g. ``axis = 1, value = 0``
    for the symmetry plane y = 0 of the quarter model), drawn in the plane's two
    other coordinates. ``window = (x0, x1, y0, y1)`` zooms. Returns the polygon
    collection (for a colour bar)."""
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import LogNorm

    mesh, d = disc.mesh, disc.dim
    eta = np.asarray(eta, dtype=float)
    if d == 2:
        polygons, elements, keys = mesh.points[mesh.cells], np.arange(mesh.n_elements), mesh.cells
        on_plane = np.ones(disc.n_contact, dtype=bool)
        plane = [0, 1]
    else:
        if axis is None:
            raise InputError("axis", "a 3D mesh is drawn as a section: give the axis normal to the plane")
        polygons, elements, keys = slice_polygons(mesh, axis, value)
        size = float(np.ptp(mesh.points, axis=0).max())
        on_plane = np.abs(mesh.points[disc.contact_nodes, axis] - value) <= 1e-9 * size
        plane = [i for i in range(3) if i != axis]
    positive = eta[eta > 0]
    top = float(positive.max()) if positive.size else 1.0
    floor = max(float(positive.min()) if positive.size else top, top * 1e-6)
    coll = PolyCollection(polygons, array=np.clip(eta[elements], floor, top), cmap="viridis",
                          norm=LogNorm(floor, top), edgecolors="k" if edges else "face",
                          linewidths=0.15 if edges else 0.0)
    ax.add_collection(coll)
    plastic = np.asarray(solution.plastic, dtype=bool)[elements]
    if plastic.any():
        ax.add_collection(LineCollection(_outline(polygons, keys, plastic), colors="k", linewidths=1.2,
                                         label="plastic zone"))
    active = np.asarray(solution.active, dtype=bool) & on_plane
    if active.any():
        xy = mesh.points[disc.contact_nodes[active]][:, plane]
        xy = xy[np.argsort(xy[:, 0])]
        ax.plot(xy[:, 0], xy[:, 1], "-", color="red", lw=3, solid_capstyle="butt", label="contact")
        ends = xy[[0, -1]]
        centre = disc.problem.obstacle.center[plane[0]] if disc.problem.obstacle.center else np.inf
        size = float(np.ptp(mesh.points, axis=0).max())
        ends = ends[np.abs(ends[:, 0] - centre) > 1e-9 * size]  # an end at the centre lies on a symmetry plane
        ax.plot(ends[:, 0], ends[:, 1], "^", color="red", ms=8, mec="k", label="contact edge")
    if window is None:
        lo, hi = polygons.reshape(-1, 2).min(axis=0), polygons.reshape(-1, 2).max(axis=0)
        window = (lo[0], hi[0], lo[1], hi[1])
    ax.set_xlim(window[0], window[1])
    ax.set_ylim(window[2], window[3])
    ax.set_aspect("equal")
    names = "xyz"
    ax.set_xlabel(names[plane[0]])
    ax.set_ylabel(names[plane[1]])
    return coll


def zoom_window(disc: Discretization, solution: Solution, *, axis: int | None = None,
                factor: float = 2.0) -> tuple[float, float, float, float]:
    """A window ``(x0, x1, y0, y1)`` for :func:`draw_indicator` around the contact and
    plastic zones: ``factor`` times their reach from the obstacle's centre (the
    contact zone's middle without one), sideways and in depth, clipped to the mesh."""
    plane = [0, 1] if disc.dim == 2 else [i for i in range(3) if i != axis]
    pts = disc.mesh.points
    contact = pts[disc.contact_nodes]
    centre_of = disc.problem.obstacle.center
    centre = float(centre_of[plane[0]]) if centre_of else float(0.5 * (contact[:, plane[0]].min()
                                                                        + contact[:, plane[0]].max()))
    base = float(contact[:, plane[1]].min())
    mid = pts[disc.mesh.cells].mean(axis=1)
    near = np.concatenate([contact[np.asarray(solution.active, dtype=bool)], mid[np.asarray(solution.plastic, dtype=bool)]])
    reach = max(float(np.abs(near[:, plane[0]] - centre).max(initial=0.0)),
                float(np.abs(near[:, plane[1]] - base).max(initial=0.0)))
    if reach <= 0:
        reach = float(np.ptp(contact[:, plane[0]]))
    x0 = max(float(pts[:, plane[0]].min()), centre - factor * reach)
    x1 = min(float(pts[:, plane[0]].max()), centre + factor * reach)
    return x0, x1, base, base + factor * reach


def plot_indicator(path, disc: Discretization, solution: Solution, bounds: Bounds, *, axis: int | None = None,
                   value: float = 0.0, title: str = "") -> None:
    """Two panels, the whole mesh and a zoom on the contact and plastic zones, of
    :func:`draw_indicator` with the marking indicator
    (:func:`~elastoplast.bounds.upper.element_indicators`). 3D: the section ``x[axis] =
    value`` (default: the plane y = 0 through the contact centre, a symmetry plane
    of the quarter model)."""
    from matplotlib.figure import Figure

    if disc.dim == 3 and axis is None:
        axis, value = 1, float(disc.problem.obstacle.center[1]) if disc.problem.obstacle.center else 0.0
    eta = element_indicators(disc, bounds)
    fig = Figure(figsize=(11.0, 4.4), layout="constrained")
    ax = fig.subplots(1, 2)
    coll = draw_indicator(ax[0], disc, solution, eta, axis=axis, value=value, edges=disc.n_elements < 20_000)
    draw_indicator(ax[1], disc, solution, eta, axis=axis, value=value,
                   window=zoom_window(disc, solution, axis=axis))
    ax[0].set_title(f"{disc.n_elements:,} elements" + (f", section {'xyz'[axis]} = {value:g}" if disc.dim == 3 else ""))
    ax[1].set_title("contact and plastic zones")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.colorbar(coll, ax=ax, label="local gap (marking indicator)", shrink=0.9)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=130)


# ----------------------------------------------------------------------------
# the command: run, compare with uniform refinement, write everything
# ----------------------------------------------------------------------------


def write_table(path, adaptive: AdaptResult, uniform_run: AdaptResult | None) -> str:
    """The steps as a Markdown table (adaptive, then uniform), with the fitted rates."""
    head = "| run | step | elements | lower | upper | relative gap | U lower | U upper | s | certified |"
    lines = [head, "|" + "---|" * 10]
    for name, run in (("adaptive", adaptive), ("uniform", uniform_run)):
        if run is None:
            continue
        for s in run.steps:
            lines.append(f"| {name} | {s.step} | {s.n_elements} | {s.energy_lower:.10g} | {s.energy_upper:.10g} | "
                         f"{s.gap_rel:.3e} | {s.U_lower:.6g} | {s.U_upper:.6g} | {s.seconds:.1f} | "
                         f"{'yes' if s.certified else 'no'} |")
    lines += ["", f"Stopped: {adaptive.reason}.", "",
              f"Fitted rate of the relative gap in the number of elements (gap ~ N^-p): adaptive p = "
              f"{fitted_rate(adaptive.steps):.3f}"
              + ("" if uniform_run is None else f", uniform p = {fitted_rate(uniform_run.steps):.3f}") + "."]
    text = "\n".join(lines) + "\n"
    from pathlib import Path

    Path(path).write_text(text)
    return text


def run_adapt_command(problem: Problem, options: AdaptOptions, out_dir) -> bool:
    """``elastoplast adapt``: the adaptive run (one line per step on stdout, a
    progress bar on stderr), the uniform comparison (``compare_uniform``: every
    element refined, from the same mesh up to the adaptive run's final size,
    within the same element budgets and what the adaptive run left of
    ``time_limit``: the limit bounds the whole command), and the files: ``adapt.md``/``adapt.json`` (the
    table), ``gap.png``, ``indicator.png`` (the final mesh coloured by the
    marking indicator, :func:`plot_indicator`), ``meshes/mesh_NNN.msh`` (every
    adapted mesh, gmsh format with the facet groups), and
    ``solution.vtu``/``summary.json`` of the final mesh with its bounds and local
    gaps. Returns whether the final bounds are certified and reach ``rtol``."""
    import sys

    from tqdm.auto import tqdm

    from elastoplast.bounds.bracket import gap_fields
    from elastoplast.mesh.base import write_mesh
    from elastoplast.io.output import json_text, staged_output, write_files
    from elastoplast.io.provenance import stamp

    with staged_output(out_dir, "--out") as tmp:
        bar = tqdm(total=options.max_iter, desc="adapt", unit="mesh", disable=not options.progress, file=sys.stderr,
                   leave=False)

        def report(step: Step) -> None:
            bar.update(1)
            bar.set_postfix(gap=f"{step.gap_rel:.2e}", elements=step.n_elements)
            tqdm.write(step.line(), file=sys.stdout)

        t0 = time.perf_counter()
        run = adapt(problem, options, report=report)
        bar.close()
        uni = None
        left = None if options.time_limit is None else options.time_limit - (time.perf_counter() - t0)
        if options.compare_uniform and left is not None and left <= 0:
            print("uniform refinement skipped: the time limit is spent", file=sys.stdout)
        elif options.compare_uniform and left is not None and left < run.steps[0].seconds:  # its first mesh is the same
            print(f"uniform refinement skipped: {left:.0f} s left, its first mesh took {run.steps[0].seconds:.0f} s",
                  file=sys.stdout)
        elif options.compare_uniform:
            print("uniform refinement, for comparison:", file=sys.stdout)
            uni = uniform(problem, replace(options, time_limit=left),
                          max_elements=max(run.final.n_elements, problem.mesh.n_elements),
                          report=lambda s: tqdm.write(s.line(), file=sys.stdout))
        (tmp / "meshes").mkdir()
        for k, mesh in enumerate(run.meshes):
            write_mesh(tmp / "meshes" / f"mesh_{k:03d}.msh", mesh)
        write_table(tmp / "adapt.md", run, uni)
        (tmp / "adapt.json").write_text(json_text({
            "reason": run.reason, "options": options.persistent(),
            "adaptive": [s.as_dict() for s in run.steps], "adaptive_rate": fitted_rate(run.steps),
            "uniform": None if uni is None else [s.as_dict() for s in uni.steps],
            "uniform_rate": None if uni is None else fitted_rate(uni.steps), "provenance": stamp()}))
        plot_gaps(tmp / "gap.png", run, uni, title=f"certified gap, {problem.dim}D")
        b = run.bounds
        plot_indicator(tmp / "indicator.png", run.disc, run.solution, b)
        final = run.final
        write_files(tmp, run.disc, run.solution,
                    extra={**b.as_dict(), "U_lower": final.U_lower, "U_upper": final.U_upper,
                           "adapt_steps": len(run.steps), "adapt_reason": run.reason},
                    **gap_fields(run.disc, b))
    print(f"{run.reason}: {final.n_elements:,} elements, relative gap {final.gap_rel:.3e}"
          + ("" if math.isnan(final.U_lower) else f", U in [{final.U_lower:.6g}, {final.U_upper:.6g}]")
          + f" -> {out_dir}")
    return bool(final.certified and final.gap_rel <= options.rtol)
