"""Budgets planned for, not found out by overrunning them: the next mesh that fits the element, memory and time budgets.

The cost of bounding a mesh is predicted from the steps so far (:func:`predicted_seconds`); when
the mesh Dörfler's θ asks for would not fit, θ is lowered by bisection to the largest value whose
mesh fits (:func:`next_mesh`)."""

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


def cost_model(steps: list[Step], bracket: bool) -> tuple[int, float, float]:
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
    n_last, cost, a = cost_model(steps, bracket)
    return cost * (n_elements / n_last) ** a


def affordable_elements(steps: list[Step], seconds: float, bracket: bool) -> int:
    """The largest mesh whose :func:`predicted_seconds` is at most ``seconds``."""
    n_last, cost, a = cost_model(steps, bracket)
    if seconds <= 0:
        return 0
    return int(n_last * (seconds / cost) ** (1.0 / a)) if cost > 0 else 2**62


def next_mesh(mesh: Mesh, state: BisectionState | None, eta: np.ndarray, theta: float, allowed: int,
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
