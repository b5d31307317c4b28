"""Depth control: the rigid body's displacement U = delta prescribed, the force F unknown.

With V fixed at delta, (2.1) is the same convex problem without the force term; its
solution is the force-controlled solution at the force F(delta) that makes U = delta,
and F is the sum of the contact forces (the multiplier of the fixed U). Hencky's
problem is convex in (v, V), so its value under force control is concave in F and
U(F) = -d value / dF is nondecreasing: the force is found by a bracketing root
search on U(F) - delta, each evaluation a solve by the chosen method (any method,
built-in or plug-in, so every method handles depth control alike).

Lift-off: the unloaded body touches the rigid body first where the gap psi is
smallest; for delta <= min psi no contact node can touch, the unloaded state
(u = 0, sigma = 0) satisfies every condition and F = 0 exactly, without a solve.

The residual reported in place of the force balance is ``|U - delta| / depth``
with ``depth = delta - min psi`` the indentation depth beyond first contact (the
stated length: it is what the force responds to; delta itself depends on where
the obstacle's origin is).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from elastoplast.certificate.kkt import ROUND_OFF
from elastoplast.certificate.solution import Solution, Status
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.options import SolverOptions
from elastoplast.solvers.path import PathResult, PathStep, run_path
from elastoplast.solvers.registry import DEFAULT_METHOD, get_method, given_options, solve

DEPTH_TOL = 1e-7  # default bound on |U - delta| / depth
MAX_EVALUATIONS = 60
#: in a path step the unloaded gap is unknown (the state springs back): lift-off is a force
#: below this share of the path's largest force so far reaching delta (the step is solved there)
FLOOR_SHARE = 1e-6


@dataclass(frozen=True)
class DepthSolution:
    """The answer of a depth-controlled solve.

    ``force`` the unknown F (the contact force sum), ``solution`` the solve at that
    force (None at lift-off, where u = 0 and sigma = 0 exactly), ``residual``
    ``|U - delta| / depth`` (0 at lift-off), ``forces``/``depths`` every evaluation
    of the root search in order.
    """

    delta: float
    force: float
    solution: Solution | None
    residual: float
    lift_off: bool
    depth: float
    forces: tuple[float, ...] = field(default=())
    depths: tuple[float, ...] = field(default=())

    @property
    def U(self) -> float:
        return self.delta if self.solution is None else float(self.solution.U)

    @property
    def converged(self) -> bool:
        return self.lift_off or (self.solution is not None and self.solution.converged)

    def summary(self) -> dict[str, Any]:
        """What a summary reports under depth control: the prescribed delta, the
        force found (the contact force sum), U and the residual replacing the force balance."""
        out: dict[str, Any] = {"control": "displacement", "displacement": self.delta, "force": self.force,
                               "U": self.U, "depth_residual": self.residual, "depth_scale": self.depth,
                               "lift_off": self.lift_off, "force_evaluations": len(self.forces)}
        if self.solution is not None:
            out["contact_force_sum"] = float(np.sum(self.solution.contact_force))
            out["status"] = self.solution.status.value
        else:
            out["contact_force_sum"] = 0.0
            out["status"] = "converged"
        return out


#: the time limit of a solve started once a search's budget is spent (it stops after one iteration)
SPENT = 1e-9


def time_left(opts: SolverOptions):
    """``opts`` with ``time_limit`` what is left, from now, of its own: a depth search makes
    many solves and ``time_limit`` bounds them together (a solve started when nothing is
    left gets ``SPENT`` and ends with status ``time_limit``, which ends the search)."""
    if opts.time_limit is None:
        return lambda: opts
    end = time.perf_counter() + opts.time_limit
    return lambda: replace(opts, time_limit=max(end - time.perf_counter(), SPENT))


def floor_share(tol: float) -> float:
    """The share of the largest force so far at which a depth path's step looks for
    lift-off: ``FLOOR_SHARE``, or more where the method's ``tol`` cannot be certified
    there. After loading, the state's stresses (of the size of the largest force) enter
    every contact force computed, which then carries their round-off, ``ROUND_OFF`` times
    that size; the force balance is relative to the step's F, so F must be at least
    ``ROUND_OFF / tol`` of it (newton's tol 1e-10: 1.4e-4; measured on a cylinder, a
    step at 1e-6 stalled at a force-balance residual of 7e-10)."""
    return max(FLOOR_SHARE, ROUND_OFF / tol)


def check_displacement(delta: Any, field_name: str = "load.displacement") -> float:
    """``delta`` as a finite float, or an :class:`InputError` naming ``field_name``.
    Any sign is allowed (a delta at or below the unloaded gap is a lift-off)."""
    if isinstance(delta, (bool, np.bool_)) or not isinstance(delta, (int, float, np.integer, np.floating)):
        raise InputError(field_name, f"must be a number (the indenter's displacement), got {delta!r}")
    value = float(delta)
    if not math.isfinite(value):
        raise InputError(field_name, f"must be finite, got {value!r}")
    return value


def solve_depth(disc: Discretization, delta: float, method: str = DEFAULT_METHOD,
                options: SolverOptions | None = None, *, depth_tol: float = DEPTH_TOL,
                force_guess: float | None = None, **values: Any) -> DepthSolution:
    """Solve (2.1) with the rigid body's displacement fixed at ``delta`` by ``method``.

    ``delta`` defaults to nothing: give it, or discretise a problem with ``[load]
    displacement`` and pass ``disc.problem.displacement``. ``force_guess`` (default
    ``disc.force``) is the first force tried. The search keeps a bracket [F_lo, F_hi]
    with U(F_lo) <= delta <= U(F_hi), starting from F_lo = 0 (U(0+) = min psi), and
    narrows it by regula falsi with the Illinois modification until
    ``|U - delta| <= depth_tol * depth``. An :class:`InputError` ``load.displacement``
    when no force reaches delta (a solve fails: above the limit load).
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    delta = check_displacement(delta)
    if disc.problem.displacement_path is not None:
        raise InputError("load.displacement_path", "is a depth path: solve it with ep.solve_depth_path")
    check_depth_tol(depth_tol)
    get_method(method)
    opts = given_options(method, options, values)
    touch = float(np.min(disc.psi))
    if delta - touch <= 0:
        return DepthSolution(delta, 0.0, None, 0.0, True, delta - touch)
    first = disc.force if force_guess is None else check_force_guess(disc, force_guess)
    left = time_left(opts)
    return find_force(lambda f: solve(disc.with_force(f), method, left()), delta, 0.0, touch, first, depth_tol)


def check_force_guess(disc: Discretization, force_guess: Any) -> float:
    """``force_guess`` as a float: a finite number > 0 (not a string, not a boolean) that
    ``disc.with_force`` takes (within the magnitudes a solver can scale), else an
    :class:`InputError` naming ``force_guess`` (not the problem's ``load.force``)."""
    if isinstance(force_guess, (bool, np.bool_)) or not isinstance(force_guess, (int, float, np.integer, np.floating)) \
            or not math.isfinite(force_guess) or not force_guess > 0:
        raise InputError("force_guess", f"must be a finite number > 0, got {force_guess!r}")
    try:
        disc.with_force(float(force_guess))
    except InputError as exc:
        raise InputError("force_guess", exc.message) from None
    return float(force_guess)


def check_depth_tol(depth_tol: Any) -> None:
    if isinstance(depth_tol, bool) or not isinstance(depth_tol, float) or not 0 < depth_tol < 1:
        raise InputError("depth_tol", f"must be a float in (0, 1), got {depth_tol!r}")


def find_force(at, delta: float, lo_f: float, lo_u: float, first: float, depth_tol: float,
               lo_sol: Solution | None = None) -> DepthSolution:
    """The force F with U(F) = delta, ``at(F)`` a solve: the bracket starts at
    (``lo_f``, ``lo_u``) (U(lo_f) = lo_u < delta) and grows from ``first`` by doubling
    until U >= delta (halving towards lo_f when a solve fails: above the limit load),
    then regula falsi (Illinois) to ``|U - delta| <= depth_tol * (delta - lo_u)`` at
    lo_f = 0 (the depth beyond first contact)."""
    depth = delta - lo_u
    forces: list[float] = []
    depths: list[float] = []

    failed: list[str] = []  # why the last solve that did not converge did not: the search's own limit

    def solve_at(force: float) -> Solution:
        if len(forces) >= MAX_EVALUATIONS:
            why = f"; the forces above it fail: {failed[-1]}" if failed else ""
            raise InputError("load.displacement", f"no force found for U = {delta:g} in {MAX_EVALUATIONS} solves "
                                                  f"(last F = {forces[-1]:g}, U = {depths[-1]:g}{why})")
        try:
            sol = at(force)
        except InputError as exc:  # a force the checks refuse (above the limit load, too large a pressure)
            if exc.field != "load.force":
                raise
            sol = None
            failed.append(f"F = {force:g} refused ({exc.message})")
        if sol is not None and not sol.converged:
            failed.append(f"F = {force:g} {sol.status.value} ({sol.message})")
        forces.append(force)
        depths.append(float("nan") if sol is None else float(sol.U))
        if sol is not None and sol.status is Status.TIME_LIMIT:
            raise _Spent(DepthSolution(delta, force, sol, abs(float(sol.U) - delta) / depth, False, depth,
                                       tuple(forces), tuple(depths)))
        return sol

    try:
        return _search(solve_at, delta, lo_f, lo_u, first, depth_tol, lo_sol, forces, depths)
    except _Spent as spent:  # the time limit: the last solve, not converged, is the answer
        return spent.answer


class _Spent(Exception):
    def __init__(self, answer: DepthSolution):
        super().__init__("time limit")
        self.answer = answer


def _search(solve_at, delta: float, lo_f: float, lo_u: float, first: float, depth_tol: float,
            lo_sol: Solution | None, forces: list[float], depths: list[float]) -> DepthSolution:
    """The bracket and regula falsi of :func:`find_force`, each solve by ``solve_at``."""
    depth = delta - lo_u
    lo_g = lo_u - delta
    hi_f = max(first, 2.0 * lo_f)
    sol = solve_at(hi_f)
    while sol is None or not sol.converged or sol.U < delta:
        if sol is None or not sol.converged:  # too far: back towards the bracket's low end
            hi_f = 0.5 * (lo_f + hi_f)
        else:
            lo_f, lo_g, lo_sol = hi_f, float(sol.U) - delta, sol
            hi_f *= 2.0
        sol = solve_at(hi_f)
    hi_g = float(sol.U) - delta
    best, best_f = sol, hi_f
    if lo_sol is not None and abs(lo_g) < abs(hi_g):
        best, best_f = lo_sol, lo_f
    side = 0
    while abs(float(best.U) - delta) > depth_tol * depth:
        f = (lo_f * hi_g - hi_f * lo_g) / (hi_g - lo_g)
        if not lo_f < f < hi_f:
            f = 0.5 * (lo_f + hi_f)
        sol = solve_at(f)
        if sol is None or not sol.converged:
            raise InputError("load.displacement", f"the solve at F = {f:g} inside the bracket did not converge"
                                                  + ("" if sol is None else f" ({sol.status.value}: {sol.message})"))
        g = float(sol.U) - delta
        if abs(g) < abs(float(best.U) - delta):
            best, best_f = sol, f
        if g > 0:
            hi_f, hi_g = f, g
            if side == 1:
                lo_g *= 0.5  # Illinois: halve the stale end's value
            side = 1
        else:
            lo_f, lo_g = f, g
            if side == -1:
                hi_g *= 0.5
            side = -1
    residual = abs(float(best.U) - delta) / depth
    return DepthSolution(delta, float(best_f), best, residual, False, depth, tuple(forces), tuple(depths))


def solve_depth_path(disc: Discretization, depths: Any, method: str = "conic", *,
                     options: SolverOptions | None = None, depth_tol: float = DEPTH_TOL, callback=None,
                     **values: Any) -> tuple[PathResult, list[DepthSolution]]:
    """A loading path by depth: one backward-Euler step of Prandtl-Reuss' law per
    prescribed displacement, each step's force found as :func:`solve_depth` finds it
    (the first guess is the last step's force). A step whose depth the body no longer
    reaches (unloading past the residual imprint) is a lift-off: it is solved at
    :func:`floor_share` times the largest force so far (F = 0 to that share; the residual
    imprint is that step's U). Returns the path (``forces`` of its steps are the found
    forces; ``result.forces`` holds the prescribed depths) and each step's search.
    """
    from elastoplast.problem.load import check_depths

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    if disc.state is not None:
        raise InputError("disc", "is already a step of a path: give the problem's discretisation (ep.discretize)")
    depths = check_depths(depths, "depths")
    check_depth_tol(depth_tol)
    m_run = get_method(method)
    opts = given_options(method, options, values)
    searches: list[DepthSolution] = []
    largest = [0.0]

    def step_solve(make_step, delta: float, prev: PathStep | None, before: PathStep | None,
                   step_opts: SolverOptions):
        left = time_left(step_opts)

        def at(f: float) -> Solution:
            return solve(make_step(f), m_run.name, left())

        if prev is None:
            touch = float(np.min(disc.psi))
            first = disc.force
            if delta <= touch:  # lift-off from the unloaded state: the step at F -> 0+
                floor = FLOOR_SHARE * first
                sol = at(floor)
                search = DepthSolution(delta, floor, sol, 0.0, True, delta - touch, (floor,), (float(sol.U),))
            else:
                search = find_force(at, delta, 0.0, touch, first, depth_tol)
        else:
            floor = floor_share(step_opts.tol) * max(largest[0], prev.force)
            low = at(floor)
            if not low.converged or low.U >= delta:
                search = DepthSolution(delta, floor, low, 0.0, True, delta - float(low.U), (floor,), (float(low.U),))
            else:
                search = find_force(at, delta, floor, float(low.U), max(prev.force, 2.0 * floor), depth_tol, low)
        largest[0] = max(largest[0], search.force)
        searches.append(search)
        return search.solution, search.force, False

    result = run_path(disc, depths, m_run.name, opts, step_solve, callback)
    return replace(result, control="displacement"), searches
