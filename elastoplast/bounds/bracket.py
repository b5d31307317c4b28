"""The certified bracket of the continuous problem: energy, the rigid body's displacement U, the stress error, and the local gaps (docs/bounds.md).

An upper bound (:mod:`elastoplast.bounds.upper`) and a lower bound (:mod:`elastoplast.bounds.lower`)
of the same problem bracket its energy; both at the forces F - delta and F + delta bracket U
through the concavity of the energy in F; the gap bounds the energy norm of the stress
error and, split element by element, is the indicator that drives adaptivity."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from elastoplast.bounds.upper import (
    BRACKET_RETRIES,
    GAP_FLOOR,
    UpperBound,
    best_upper_bound,
    upper_bound,
)
from elastoplast.errors import InputError, expect
from elastoplast.fem.axisymmetry import check_not_axisymmetric
from elastoplast.fem.discretize import Discretization, check_hencky
from elastoplast.certificate.kkt import real_number
from elastoplast.certificate.solution import check_solution


@dataclass(frozen=True)
class Bounds:
    """``energy_lower = -J <= Pi* <= energy_upper = Pi`` and what follows from it.

    ``energy_gap_rel = (upper - lower) / |upper|``; ``stress_error_bound =
    sqrt(2 gap)`` bounds ``‖σ̂ - τ̂‖`` (τ̂ the lower bound's field) and
    ``‖σ̂ - R(ε(v))‖`` in the energy norm, ``stress_error_bound_rel`` divides it by
    ``sqrt([R(ε(v)), R(ε(v))])``. ``element_gap`` = ``∫_T [W(ε(v)) + 1/2 Aτ:τ +
    η²/2H - τ:ε(v)]`` and ``facet_gap`` = ``∫_f λ (v_d - V) + Σ_a q_fa λ_a`` (q the
    lower bound's obstacle weights, ``∫_f λ I_h psi`` for a convex psi) on the
    lower bound's contact facets: each ≥ 0, and they sum to ``upper - lower``
    for an exactly admissible stress field. They are indicators; only the sum is a
    proof.
    """

    energy_lower: float
    energy_upper: float
    energy_gap_rel: float
    stress_error_bound: float
    stress_error_bound_rel: float
    bounds_certified: bool
    element_gap: np.ndarray = field(repr=False)
    facet_gap: np.ndarray = field(repr=False)
    contact_facets: np.ndarray = field(repr=False)

    @property
    def energy_gap(self) -> float:
        return self.energy_upper - self.energy_lower

    def as_dict(self) -> dict:
        """The keys ``summary.json`` gains."""
        return {
            "energy_lower": self.energy_lower,
            "energy_upper": self.energy_upper,
            "energy_gap_rel": self.energy_gap_rel,
            "stress_error_bound": self.stress_error_bound,
            "stress_error_bound_rel": self.stress_error_bound_rel,
            "bounds_certified": self.bounds_certified,
        }


def combine(upper: UpperBound, lower) -> Bounds:
    """The bracket of an :class:`UpperBound` and a lower bound
    (:class:`elastoplast.bounds.lower.LowerBound`) on the same mesh, with the local
    gap terms integrated exactly (τ, η linear per element and ε(v) constant; λ and
    ``v_d - V`` linear on a facet)."""
    from elastoplast.bounds.lower import LowerBound
    from elastoplast.bounds.static import mass_matrix
    from elastoplast.mesh.topology import facet_measure

    expect(upper, UpperBound, "upper", "ep.upper_bound(disc, solution)")
    expect(lower, LowerBound, "lower", "ep.solve_lower_bound(disc)")
    if np.shape(lower.local.element_energy) != np.shape(upper.element_energy):
        raise InputError("lower", "is the lower bound of another mesh than the upper bound")
    lo, hi = -float(lower.J), upper.Pi
    gap = hi - lo
    local = lower.local
    with np.errstate(all="ignore"):  # a non-finite side is not certified (its message says why) and is caught below
        element = upper.element_energy + local.element_energy - np.einsum("ek,ek->e", local.element_stress,
                                                                          upper.strain)
        cf = lower.field.contact_facets
        d = upper.points.shape[1]
        w = upper.u[cf, d - 1] - upper.V  # v_d - V at the facet vertices
        measure = facet_measure(upper.points[cf])
        facet = measure * np.einsum("fa,ab,fb->f", lower.field.lam, mass_matrix(d - 1), w) + local.facet_psi_work
        ordered = bracket_holds(lo, hi)
        # a gap below 0 within round-off is 0; an inverted bracket has no error bound
        err = float(np.sqrt(2.0 * max(gap, 0.0))) if ordered else math.nan
        rel = float(gap / abs(hi)) if hi != 0 else np.inf
    if not ordered:
        warnings.warn(f"the energy bracket is inverted or not finite (lower {lo:.8g} > upper {hi:.8g}): not certified")
    return Bounds(
        energy_lower=lo,
        energy_upper=hi,
        energy_gap_rel=rel,
        stress_error_bound=err,
        stress_error_bound_rel=err / upper.stress_norm if upper.stress_norm > 0 else np.inf,
        bounds_certified=bool(upper.certified and lower.certified and ordered),
        element_gap=element,
        facet_gap=facet,
        contact_facets=cf,
    )


def bracket_holds(lower: float, upper: float) -> bool:
    """Whether ``lower <= upper`` is a bracket: both finite, in order to the round-off of the
    bounds themselves (:data:`~elastoplast.bounds.upper.GAP_FLOOR` of their magnitude). Two
    valid bounds always are; an inverted pair proves that one of them is not a bound."""
    if not (math.isfinite(lower) and math.isfinite(upper)):
        return False
    return lower <= upper + GAP_FLOOR * max(abs(lower), abs(upper))


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


def u_bracket(disc: Discretization, delta: float, solve_bounds_at: Callable[[float], tuple[float, float]]) -> tuple[float, float]:
    """``(U_lower, U_upper)`` containing the continuum U at ``disc.force``.

    ``Pi*(F)`` is a minimum of functions affine in F, so it is concave with
    supergradient ``-U(F)``: ``Pi*(F') <= Pi*(F) - U(F) (F' - F)``. With
    ``lo <= Pi* <= hi`` from ``solve_bounds_at(F) -> (lo, hi)`` at ``F - delta``,
    F and ``F + delta``:

        U(F) <= (hi(F) - lo(F + delta)) / delta,   U(F) >= (lo(F - delta) - hi(F)) / delta.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    F = disc.force
    delta = real_number("delta", delta)
    if not 0 < delta < F:
        raise InputError("delta", f"must lie in (0, F) = (0, {F:g}), got {delta!r}")
    if not callable(solve_bounds_at):
        raise InputError("solve_bounds_at", "expected a function F -> (lower, upper) such as bounds_at(disc), "
                                            f"got {type(solve_bounds_at).__name__}")
    lo_m, _ = solve_bounds_at(F - delta)
    _, hi_0 = solve_bounds_at(F)
    lo_p, _ = solve_bounds_at(F + delta)
    return u_secants(lo_m, hi_0, lo_p, delta, delta)


def u_secants(lower_minus: float, upper: float, lower_plus: float, delta_minus: float,
              delta_plus: float) -> tuple[float, float]:
    """The secant bounds of :func:`u_bracket`: ``U(F) >= (lo(F - delta_minus) - hi(F)) / delta_minus``
    and ``U(F) <= (hi(F) - lo(F + delta_plus)) / delta_plus`` (each side holds for its own delta)."""
    return (lower_minus - upper) / delta_minus, (upper - lower_plus) / delta_plus


def choose_delta(force: float, gap: float, dU_dF: float) -> float:
    """The δ that minimises the predicted width of :func:`u_bracket`.

    With ``lo = Pi* - e_lo`` and ``hi = Pi* + e_hi``, the width is

        [2 Pi*(F) - Pi*(F + δ) - Pi*(F - δ)] / δ + [2 e_hi(F) + e_lo(F + δ) + e_lo(F - δ)] / δ
        ≈ U'(F) δ + G / δ,

    since ``Pi*'' = -U'``. Taking the gaps at the three loads equal and split
    evenly, ``G ≈ 2 gap``, so ``δ* = sqrt(2 gap / U')`` and the width is about
    ``2 sqrt(2 gap U')``. ``U'`` is estimated from discrete solutions
    (:func:`displacement_slope`). δ is kept below ``F / 2``.
    """
    force = real_number("force", force)
    if not (math.isfinite(force) and force > 0):
        raise InputError("force", f"must be a finite number > 0, got {force!r}")
    gap, dU_dF = real_number("gap", gap), real_number("dU_dF", dU_dF)
    if not (gap > 0 and dU_dF > 0):
        return 0.5 * force
    return float(min(np.sqrt(2.0 * gap / dU_dF), 0.5 * force))


def displacement_slope(disc: Discretization, method: str = "conic", step: float = 0.05, **options) -> float:
    """``dU/dF`` of the discrete problem by a central difference ``±step F``
    (used only to choose δ, so its accuracy does not matter for the bound)."""
    from elastoplast.solvers.registry import solve

    F = disc.force
    U = [solve(disc.with_force(F * (1 + s)), method, **options).U for s in (-step, step)]
    return float((U[1] - U[0]) / (2.0 * step * F))


def lower_kind(lower) -> str:
    """``"local"`` or ``"global"``: which lower bound ``lower`` is (its ``solver``)."""
    return "local" if getattr(lower, "solver", "") == "local" else "global"


@dataclass(frozen=True)
class BoundsReport:
    """The energy bracket of one problem (:class:`Bounds`), the U bracket from the
    lower bounds at ``F -/+ delta`` (NaN when not computed), and the two sides it
    was built from, for their messages and local terms."""

    bounds: Bounds
    upper: UpperBound = field(repr=False)
    lower: object = field(repr=False)
    U_lower: float = float("nan")
    U_upper: float = float("nan")
    delta: tuple[float, float] = (float("nan"), float("nan"))
    timings: dict = field(default_factory=dict)

    @property
    def certified(self) -> bool:
        """The energy bracket is a proof; with a U bracket, its two extra lower bounds are too."""
        return self.bounds.bounds_certified and self.bracket_certified

    bracket_certified: bool = True

    def as_dict(self) -> dict:
        """The keys ``summary.json`` gains (docs/bounds.md)."""
        return {
            **self.bounds.as_dict(),
            "bounds_certified": self.certified,
            "U_lower": self.U_lower,
            "U_upper": self.U_upper,
            "U_bracket_delta": self.delta[0],
            "U_bracket_delta_above": self.delta[1],
            "upper_bound": {"penetration": self.upper.penetration, "shift": self.upper.shift, "lift": self.upper.lift,
                            "certified": self.upper.certified, "message": self.upper.message},
            "lower_bound_kind": lower_kind(self.lower),
            "lower_bound": {"kind": lower_kind(self.lower), "solver": self.lower.solver,
                            "certified": self.lower.certified, "status": self.lower.status.value,
                            "message": self.lower.message, "certificate_worst": self.lower.certificate.worst,
                            "iterations": self.lower.iterations},
            "bounds_timings": self.timings,
        }


#: ``progress(fraction, what)``: how far a lower bound (or a U bracket) is, ``fraction`` in [0, 1]
Progress = Callable[[float, str], None]


def check_progress(progress) -> None:
    if progress is not None and not callable(progress):
        raise InputError("progress", f"expected a function progress(fraction, what) or None, got "
                                     f"{type(progress).__name__}")


def scaled_progress(progress: Progress | None, start: float, end: float) -> Progress | None:
    """``progress`` for a part of the work that spans ``[start, end]`` of the whole."""
    if progress is None:
        return None

    def report(fraction: float, what: str) -> None:
        progress(start + (end - start) * min(max(float(fraction), 0.0), 1.0), what)

    return report


def check_lower_bound_fits(disc: Discretization, options=None, factor: float = 1.0) -> str:
    """Refuse, before any work, a mesh the chosen lower bound
    (:func:`~elastoplast.bounds.lower.lower_bound_kind`) cannot finish: the global program by
    :func:`~elastoplast.bounds.lower.check_lower_bound_size` (its size limit and memory,
    ``factor`` for several in a row), the local bound when its estimate
    (:func:`~elastoplast.bounds.lower.lower_bound_bytes`, with its solve, the sweeps alone:
    :func:`local_descent` drops the descent where it does not fit)
    exceeds the memory available. Returns the kind, ``"global"`` or ``"local"``."""
    check_not_axisymmetric(disc.problem, "the certified bounds")
    from elastoplast.bounds.lower import LowerBoundOptions, check_lower_bound_size, lower_bound_bytes, lower_bound_kind
    from elastoplast.limits import check_memory

    options = LowerBoundOptions.of(options, "lower_options")
    kind = lower_bound_kind(disc, options)
    if kind == "global":
        check_lower_bound_size(disc, options, factor=factor)
    else:  # the sweeps alone where the descent does not fit (local_descent)
        check_memory(lower_bound_bytes(disc.dim, disc.n_elements, kind, descent=False), "mesh",
                     f"the local lower bound ({disc.n_elements:,} elements, with its P1 solve, even without its "
                     "descent)", "coarsen the mesh")
    return kind


def local_descent(disc: Discretization, options) -> int:
    """The descent steps the local bound takes on ``disc``: ``options.descent`` (None:
    :data:`~elastoplast.bounds.local.construction.DESCENT_STEPS`), or 0, with a warning, where its
    estimate with the descent (:func:`~elastoplast.bounds.lower.lower_bound_bytes`) exceeds
    the memory available now (where even the sweeps alone do not fit,
    :func:`check_lower_bound_fits` refuses the mesh before any work)."""
    from elastoplast.bounds.local.construction import DESCENT_STEPS
    from elastoplast.bounds.lower import lower_bound_bytes
    from elastoplast.limits import available_memory, format_bytes

    steps = DESCENT_STEPS[disc.dim] if options.descent is None else options.descent
    limit, where = available_memory()
    if steps == 0 or limit is None:
        return steps
    need = lower_bound_bytes(disc.dim, disc.n_elements, "local")
    if need <= limit:
        return steps
    warnings.warn(f"the local lower bound on {disc.n_elements:,} elements: its descent over all rings would need about "
                  f"{format_bytes(need)}, {format_bytes(limit)} available ({where}); the sweeps alone run (about "
                  f"{format_bytes(lower_bound_bytes(disc.dim, disc.n_elements, 'local', descent=False))}): "
                  "certified, only looser", stacklevel=2)
    return 0


def lower_bound(disc: Discretization, solution=None, options=None, *, progress: Progress | None = None,
                upper: float | None = None):
    """The certified lower bound ``-J <= Pi*`` on ``disc`` that ``options.kind`` chooses
    (:class:`~elastoplast.bounds.lower.LowerBoundOptions`, or a mapping of them;
    :func:`~elastoplast.bounds.lower.lower_bound_kind`): the optimum of the equilibrium
    element (:func:`~elastoplast.bounds.lower.solve_lower_bound`; ``solution`` unused), or the
    local field built from ``solution``, a P1 solution of ``disc``
    (:func:`~elastoplast.bounds.local.construction.local_lower_bound`; H > 0). Either is a
    :class:`~elastoplast.bounds.lower.LowerBound`; its ``solver`` is ``"local"`` for the local
    bound. ``progress(fraction, what)`` is called as the bound advances; ``upper``, the Pi of
    an upper bound on ``disc``, lets the local bound's descent stop once it gains little
    against the gap."""
    import elastoplast.bounds.lower as global_bound
    from elastoplast.certificate.solution import Solution

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    options = global_bound.LowerBoundOptions.of(options, "lower_options")
    check_progress(progress)
    kind = global_bound.lower_bound_kind(disc, options)
    if kind == "global":
        if progress is not None:
            progress(0.0, f"lower bound: global program ({disc.n_elements:,} elements)")
        lower = global_bound.solve_lower_bound(disc, options)
    else:
        if solution is None:
            raise InputError("solution", "the local lower bound is built from a P1 solution of disc: give one "
                                         "(ep.solve(disc, 'newton')), or choose the global program (kind 'global')")
        expect(solution, Solution, "solution", "ep.solve(disc, method)")
        if progress is not None:
            progress(0.0, f"lower bound: local field ({disc.n_elements:,} elements)")
        from elastoplast.bounds.local.construction import local_lower_bound

        descent = local_descent(disc, options)
        lower = local_lower_bound(disc, solution, descent=descent, progress=progress, upper=upper)
    if progress is not None:
        progress(1.0, "lower bound done")
    return lower


def bracket_method(solution) -> str:
    """The method of the P1 solves at ``F -/+ delta``: the solution's own when it is a
    built-in method, else newton."""
    from elastoplast.solvers.registry import METHODS

    return solution.method if getattr(solution, "method", None) in METHODS else "newton"


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


def solve_at(disc: Discretization, force: float, method: str, start=None, tol: float | None = None, **options):
    """The P1 solution of ``disc`` at ``force`` by ``method`` (solver options as for
    :func:`~elastoplast.solvers.registry.solve`: an options object as ``options=`` or
    keywords; ``tol``: at most this KKT tolerance), from ``start`` (a solution of ``disc``,
    its contact forces scaled to ``force``) where the method takes a start
    (:data:`~elastoplast.solvers.path.WARM_STARTS`); cold again if that does not converge."""
    from dataclasses import replace

    from elastoplast.solvers.path import WARM_STARTS, run_from
    from elastoplast.solvers.registry import get_method, given_options

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
    import time

    from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_kind
    from elastoplast.solvers.registry import solve

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_hencky(disc, "the certified bounds")
    check_not_axisymmetric(disc.problem, "the certified bounds")
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
    from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_kind

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


def element_indicators(disc: Discretization, bounds: Bounds) -> np.ndarray:
    """The local gap of each element plus the gap of the contact facets it owns
    (clipped at 0: the terms are >= 0 for an exactly admissible field, round-off
    aside): the indicator adaptive refinement marks on."""
    topo = disc.facet_topology
    eta = np.maximum(np.asarray(bounds.element_gap, dtype=float), 0.0)
    owners = topo.boundary_elements[topo.contact]
    np.add.at(eta, owners, np.maximum(np.asarray(bounds.facet_gap, dtype=float), 0.0))
    return eta


def gap_fields(disc: Discretization, bounds: Bounds) -> dict:
    """What ``solution.vtu`` gains (:func:`elastoplast.io.output.write_vtu` keywords):
    the local gap per element and per contact facet, and the marking indicator."""
    return {"cell_data": {"gap": bounds.element_gap, "gap_indicator": element_indicators(disc, bounds)},
            "facets": (bounds.contact_facets, {"gap": bounds.facet_gap})}
