"""Budgets planned for, not found out by overrunning them: the next mesh that fits the element, memory and time budgets.

The cost of bounding a mesh is predicted from the steps so far (:func:`predicted_seconds`); when
the mesh Dörfler's θ asks for would not fit, θ is lowered by bisection to the largest value whose
mesh fits (:func:`next_mesh`). When it would grow the mesh by less than ``min_growth``, θ is first
raised until it does (:func:`raised_theta`): every mesh costs a lower bound, and small steps spend
the budget on many of them."""

from __future__ import annotations

import math

import numpy as np

from elastoplast.adapt.records import AdaptOptions, Step
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.refinement import BisectionState, dorfler_mark, refine

#: a refinement step must at least multiply the elements by this, else the loop stops
#: (a step costs a lower-bound program: one that adds a handful of elements is not worth it)
MIN_GROWTH = 1.25


#: bisection steps on θ when the marked mesh does not fit a budget
FIT_STEPS = 10

#: refinements tried when θ is raised to grow the mesh by ``min_growth``
RAISE_STEPS = 4

#: the cost exponent is fitted only over steps whose sizes span at least this ratio (1.5 below)
FIT_SPAN = 1.5


def lower_bound_budget(dim: int, options: AdaptOptions, hardening: bool = True) -> tuple[str, int]:
    """``(what limits it, elements)``: the largest mesh the lower bound of ``options.lower``
    accepts and whose lower bounds, run one after another in this process, fit in the
    memory available (:func:`~elastoplast.bounds.lower.lower_bound_fits`). The global
    program has its size limit (``lower_max_elements``, else
    :data:`~elastoplast.bounds.lower.LOWER_BOUND_MAX_ELEMENTS`) and its memory; the local
    bound only its memory (and ``lower_max_elements`` when given). ``"auto"`` takes the
    global program up to :data:`~elastoplast.bounds.lower.AUTO_GLOBAL_MAX_ELEMENTS`, so its
    budget is the local bound's when the global program fits up to there, else the global
    program's (``hardening`` False: the global program, the only lower bound with H = 0 and,
    so far, in axisymmetric models: :func:`has_local_bound`)."""
    from elastoplast.bounds.lower import AUTO_GLOBAL_MAX_ELEMENTS

    kind = options.lower if hardening else "global"
    glob = kind_budget(dim, options, "global")
    if kind == "global" or (kind == "auto" and glob[1] < AUTO_GLOBAL_MAX_ELEMENTS[dim]):
        return glob
    return kind_budget(dim, options, "local")


def has_local_bound(problem) -> bool:
    """Whether the local lower bound can run on ``problem``: H > 0 and not axisymmetric (the
    local construction in ``tau = r sigma`` is not built yet)."""
    return problem.material.hardening > 0 and not problem.axisymmetric


def kind_budget(dim: int, options: AdaptOptions, kind: str) -> tuple[str, int]:
    """:func:`lower_bound_budget` of one kind of lower bound."""
    from elastoplast.bounds.lower import LOWER_BOUND_MAX_ELEMENTS, lower_bound_fits

    default = LOWER_BOUND_MAX_ELEMENTS[dim] if kind == "global" else options.max_elements
    largest = options.lower_max_elements or default
    fits = lower_bound_fits(dim, kind=kind)
    if fits is not None and fits < largest:
        return "the memory available to the lower bound", max(1, fits)
    return "the lower bound's size limit" if options.lower_max_elements or kind == "global" else "max_elements", largest


def lower_bound_limit(dim: int, options: AdaptOptions, hardening: bool = True) -> int:
    """The elements of :func:`lower_bound_budget`."""
    return lower_bound_budget(dim, options, hardening)[1]


def bracket_seconds(step: Step) -> float:
    """The predicted cost of the U bracket of a mesh from its row: two more lower bounds and,
    with the local bound, their two P1 solves (about the row's, the problem and its
    conservative variant)."""
    return 2.0 * step.lower_seconds + (step.solve_seconds if step.lower == "local" else 0.0)


def cost_model(steps: list[Step], bracket: bool) -> tuple[int, float, float]:
    """``(N_last, cost_last, a)`` of :func:`predicted_seconds`."""
    last = steps[-1]
    same = [s for s in steps if s.lower == last.lower]  # "auto" switches lower bounds once
    n = np.array([s.n_elements for s in same], dtype=float)
    cost = np.array([s.solve_seconds + s.lower_seconds for s in same])
    a = 1.5
    if n.size >= 2 and n.max() >= FIT_SPAN * n.min() and np.all(cost > 0):
        a = float(np.clip(np.polyfit(np.log(n), np.log(cost), 1)[0], 1.0, 2.5))
    return last.n_elements, last.solve_seconds + last.lower_seconds + (bracket_seconds(last) if bracket else 0.0), a


def predicted_seconds(steps: list[Step], n_elements: int, bracket: bool) -> float:
    """The predicted cost of bounding a mesh of ``n_elements`` (with its U bracket
    when ``bracket``: :func:`bracket_seconds`), from the steps so far:
    ``cost(N) = cost_last (N / N_last)^a``, ``cost_last`` the last step's solves and
    lower bound(s), ``a`` the least-squares slope of log(solves + lower bound) in log(N) over
    all the steps with the same lower bound as the last, kept in [1, 2.5] (the interior point's cost grows like
    N^1.3-1.5 in 3D, benchmarks/bounds/lower.md; a slope outside that range is
    timing noise), 1.5 after a single step or while their sizes span less than
    :data:`FIT_SPAN`. The local bound's cost also moves with the descent steps it takes
    (13.8 s at 17,637 triangles and 41.3 s at 17,839 in one cylinder run): fitted over the
    last three steps only, that noise gave slopes from -69 to 84 in a 10-minute cylinder run,
    and another stopped with 368 s of its 600 left on a slope of 2.0 where the whole run's
    was 1.2 (its next mesh then predicted at 385 s instead of 322)."""
    n_last, cost, a = cost_model(steps, bracket)
    return cost * (n_elements / n_last) ** a


def affordable_elements(steps: list[Step], seconds: float, bracket: bool) -> int:
    """The largest mesh whose :func:`predicted_seconds` is at most ``seconds``."""
    n_last, cost, a = cost_model(steps, bracket)
    if seconds <= 0:
        return 0
    return int(n_last * (seconds / cost) ** (1.0 / a)) if cost > 0 else 2**62


def theta_marking(eta: np.ndarray, count: int) -> float:
    """The θ whose Dörfler set is the ``count`` largest indicators (and their ties): halfway
    between the shares of the ``count - 1`` and the ``count`` largest, so that the rounding
    of ``θ`` times the total cannot move the set by one."""
    ordered = np.sort(eta)[::-1]
    cumulative = np.cumsum(ordered)
    total = float(cumulative[-1]) if eta.size else 0.0
    if count <= 0 or total <= 0.0:
        return 0.0
    if count >= eta.size:
        return 1.0
    below = float(cumulative[count - 2]) if count >= 2 else 0.0
    return min(1.0, 0.5 * (below + float(cumulative[count - 1])) / total)


def raised_theta(mesh: Mesh, state: BisectionState | None, eta: np.ndarray,
                 first: tuple[Mesh, BisectionState, np.ndarray, float], growth: float, allowed: int):
    """``(mesh, state, marked, θ)``: ``first``, the refinement of Dörfler's θ, with θ raised
    until the mesh has ``growth`` times the elements (at most ``allowed``), or θ = 1, or
    :data:`RAISE_STEPS` refinements. Each try marks the number of elements the last one
    showed to be needed: the elements a marked element added there, closure included
    (about 7 in 3D), divided into the elements still missing. The result may overshoot
    ``allowed``; :func:`next_mesh` then fits it."""
    new, st, marked, theta = first
    target = min(growth * mesh.n_elements, allowed)
    for _ in range(RAISE_STEPS):
        added, count = new.n_elements - mesh.n_elements, int(marked.sum())
        if new.n_elements >= target or theta >= 1.0 or added <= 0 or count == 0:
            break
        raised = theta_marking(eta, count + math.ceil((target - new.n_elements) * count / added))
        if raised <= theta:
            break
        theta, marked = raised, dorfler_mark(eta, raised)
        new, st, _ = refine(mesh, marked, state)
    return new, st, marked, theta


def next_mesh(mesh: Mesh, state: BisectionState | None, eta: np.ndarray, theta: float, allowed: int,
              adaptive: bool, min_growth: float = 1.0
              ) -> tuple[tuple[Mesh, BisectionState, np.ndarray, float] | None, int]:
    """The refined mesh Dörfler's ``theta`` marks (every element when not ``adaptive``).

    When that mesh fits (at most ``allowed`` elements) but has fewer than ``min_growth``
    times the elements, θ is raised (:func:`raised_theta`); a raised mesh above ``allowed``
    is brought back by bisection on θ between the two, to the largest θ that fits. When
    the mesh of ``theta`` itself does not fit, θ is lowered by bisection to the largest
    smaller θ that fits (the marked sets are nested in θ, hence so are the meshes), if that
    mesh has at least ``MIN_GROWTH`` times the elements; else None.
    Returns ``((mesh, state, marked, θ) or None, elements of the mesh asked for)``."""
    marked = dorfler_mark(eta, theta) if adaptive else np.ones(eta.size, dtype=bool)
    new, st, _ = refine(mesh, marked, state)
    asked = (new, st, marked, theta if adaptive else math.nan)
    if new.n_elements <= allowed:
        if not adaptive:
            return asked, new.n_elements
        raised = raised_theta(mesh, state, eta, asked, min_growth, allowed)
        if raised[0].n_elements <= allowed:
            return raised, raised[0].n_elements
        return fitted_theta(mesh, state, eta, allowed, asked, raised[3]), raised[0].n_elements
    if not adaptive:
        return None, new.n_elements
    best = fitted_theta(mesh, state, eta, allowed, None, theta)
    if best is None or best[0].n_elements < MIN_GROWTH * mesh.n_elements:
        return None, new.n_elements
    return best, new.n_elements


def fitted_theta(mesh: Mesh, state: BisectionState | None, eta: np.ndarray, allowed: int,
                 fits: tuple[Mesh, BisectionState, np.ndarray, float] | None, too_large: float):
    """The refinement of the largest θ below ``too_large`` whose mesh has at most ``allowed``
    elements, by :data:`FIT_STEPS` bisection steps from ``fits`` (a refinement that fits, the
    lower end; None: from θ = 0, and None if no θ tried fits)."""
    best, lo, hi = fits, (0.0 if fits is None else fits[3]), too_large
    for _ in range(FIT_STEPS):
        t = 0.5 * (lo + hi)
        m = dorfler_mark(eta, t)
        cand = refine(mesh, m, state)[:2]
        if cand[0].n_elements <= allowed:
            best, lo = (cand[0], cand[1], m, t), t
        else:
            hi = t
    return best