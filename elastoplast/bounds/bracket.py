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

from elastoplast.bounds.upper import UpperBound
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.certificate.kkt import real_number


#: the smallest energy gap, relative to the energy, used to choose the U bracket's delta
GAP_FLOOR = 1e-10


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
        if lower.field.hoop is not None:  # axisymmetric: lam is the traction r p of tau = r sigma, in revolution
            measure = 2.0 * np.pi * measure
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
    bounds themselves (:data:`GAP_FLOOR` of their magnitude). Two
    valid bounds always are; an inverted pair proves that one of them is not a bound."""
    if not (math.isfinite(lower) and math.isfinite(upper)):
        return False
    return lower <= upper + GAP_FLOOR * max(abs(lower), abs(upper))


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
    element (:func:`~elastoplast.bounds.equilibrium.bound.solve_lower_bound`; ``solution`` unused), or the
    local field built from ``solution``, a P1 solution of ``disc``
    (:func:`~elastoplast.bounds.local.construction.local_lower_bound`; H > 0). Either is a
    :class:`~elastoplast.bounds.lower.LowerBound`; its ``solver`` is ``"local"`` for the local
    bound. ``progress(fraction, what)`` is called as the bound advances; ``upper``, the Pi of
    an upper bound on ``disc``, lets the local bound's descent stop once it gains little
    against the gap."""
    import elastoplast.bounds.equilibrium.bound as global_bound
    from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_kind
    from elastoplast.certificate.solution import Solution

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    options = LowerBoundOptions.of(options, "lower_options")
    check_progress(progress)
    kind = lower_bound_kind(disc, options)
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
