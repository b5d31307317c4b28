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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from elastoplast.certificate.solution import Solution
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.options import SolverOptions
from elastoplast.solvers.registry import DEFAULT_METHOD, get_method, given_options, solve

DEPTH_TOL = 1e-7  # default bound on |U - delta| / depth
MAX_EVALUATIONS = 60


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

    ``force_guess`` (default ``disc.force``) is the first force tried. The search
    keeps a bracket [F_lo, F_hi] with U(F_lo) <= delta <= U(F_hi), starting from
    F_lo = 0 (U(0+) = min psi), and narrows it by regula falsi with the Illinois
    modification until ``|U - delta| <= depth_tol * depth``. An :class:`InputError`
    ``load.displacement`` when no force reaches delta (above the limit load).
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    delta = check_displacement(delta)
    if disc.problem.path is not None:
        raise InputError("load.displacement", "depth control solves Hencky's problem here; a depth path is "
                                              "solved step by step (solve_depth_path)")
    if not (isinstance(depth_tol, float) and 0 < depth_tol < 1):
        raise InputError("depth_tol", f"must be a float in (0, 1), got {depth_tol!r}")
    get_method(method)
    opts = given_options(method, options, values)
    touch = float(np.min(disc.psi))
    depth = delta - touch
    if depth <= 0:
        return DepthSolution(delta, 0.0, None, 0.0, True, depth)
    forces: list[float] = []
    depths: list[float] = []

    def at(force: float) -> Solution:
        sol = solve(disc.with_force(force), method, opts)
        forces.append(force)
        depths.append(float(sol.U))
        return sol

    lo_f, lo_g = 0.0, touch - delta  # U(0+) = min psi
    hi_f = float(force_guess if force_guess is not None else disc.force)
    if not hi_f > 0:
        raise InputError("force_guess", f"must be > 0, got {force_guess!r}")
    sol = at(hi_f)
    while sol.U < delta:  # grow until the bracket holds delta
        if not sol.converged:
            raise InputError("load.displacement", f"the solve at F = {hi_f:g} did not converge "
                                                  f"({sol.status.value}) while looking for U = {delta:g}")
        lo_f, lo_g = hi_f, float(sol.U) - delta
        if len(forces) >= MAX_EVALUATIONS:
            raise InputError("load.displacement", f"no force up to {hi_f:g} reaches U = {delta:g}")
        hi_f *= 2.0
        sol = at(hi_f)
    hi_g = float(sol.U) - delta
    best, best_f = sol, hi_f
    side = 0
    while abs(float(best.U) - delta) > depth_tol * depth:
        if len(forces) >= MAX_EVALUATIONS:
            break
        f = (lo_f * hi_g - hi_f * lo_g) / (hi_g - lo_g)
        if not lo_f < f < hi_f:
            f = 0.5 * (lo_f + hi_f)
        sol = at(f)
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
