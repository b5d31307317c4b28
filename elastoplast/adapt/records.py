"""What an adaptive run is asked and what it gives back: its options, one row per mesh, the result; rates read off the rows."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from elastoplast.certificate.solution import Solution
from elastoplast.fem.discretize import Discretization
from elastoplast.mesh.base import Mesh
from elastoplast.options import SolverOptions, option


@dataclass(frozen=True)
class AdaptOptions(SolverOptions):
    """Settings of :func:`adapt` (declared and checked like every solver's options).

    ``tol`` here is ``rtol``'s companion for the P1 solves: the KKT tolerance
    each mesh's discrete solution is certified to (the bounds need the discrete
    solution only as a candidate, but an accurate one keeps the upper bound
    tight). ``max_iter`` bounds the number of meshes (``max_steps``).
    ``lower``: which lower bound bounds each mesh (:attr:`~elastoplast.bounds.lower.LowerBoundOptions.kind`:
    with ``"auto"`` the global program on meshes up to
    :data:`~elastoplast.bounds.lower.AUTO_GLOBAL_MAX_ELEMENTS`, the local bound above).
    ``lower_max_elements``: the lower bound's size limit (None: the global program's
    :data:`~elastoplast.bounds.lower.LOWER_BOUND_MAX_ELEMENTS`, none for the local bound
    but its memory); the loop never builds a mesh above it or above ``max_elements``.
    ``lower_descent``: the local bound's descent steps over all rings
    (:attr:`~elastoplast.bounds.lower.LowerBoundOptions.descent`).
    """

    max_iter: int = option(30, int, "most meshes solved (adaptive steps)", lo=1, hi=200)
    tol: float = option(1e-8, float, "KKT tolerance of each mesh's P1 solution", lo=1e-13, hi=1e-4)
    rtol: float = option(1e-3, float, "target relative energy gap (upper - lower) / |upper|", lo=1e-8, hi=1.0,
                         lo_open=True)
    theta: float = option(0.5, float, "Dörfler parameter: mark the smallest set carrying this share of the gap",
                          lo=0.0, hi=1.0, lo_open=True)
    min_growth: float = option(1.5, float, "raise θ until each new mesh has at least this many times the elements "
                               "(1: keep θ)", lo=1.0, hi=8.0)
    max_elements: int = option(2_000_000, int, "stop before a mesh with more elements", lo=1, hi=100_000_000)
    method: str = option("newton", str, "the P1 solver", choices=("conic", "newton", "uzawa", "uzawa-fast"))
    bracket: str = option("final", str, "U bracket on the final mesh only, at every step, or never",
                          choices=("every", "final", "never"))
    compare_uniform: bool = option(True, bool, "also run uniform refinement for the plot (command only)")
    warm_start: bool = option(True, bool, "Newton from the previous mesh's solution, interpolated", persist=False)
    lower_max_elements: int | None = option(None, int, "the lower bound's size limit (none: its default)", lo=1,
                                            hi=100_000_000, none=True)
    lower: str = option("auto", str, "the lower bound: the global program, the local field, or auto (by mesh size)",
                        choices=("auto", "local", "global"))
    lower_descent: int | None = option(None, int, "the local bound's descent steps (none: its default)", lo=0,
                                       hi=100_000, none=True)


@dataclass(frozen=True)
class Step:
    """One mesh of the sequence: its size, bounds, U bracket and cost.

    ``seconds`` is the whole step (solves, bounds, bracket, marking and
    refinement); ``solve_seconds`` the P1 solves (the problem and its
    conservative variant), ``lower_seconds`` the lower bound at F (``lower``: which
    one, ``"global"`` or ``"local"``), ``bracket_seconds`` the two at ``F ∓ δ`` (with the
    local bound, their P1 solves too); ``iterations`` the solver
    iterations of the P1 solve of the problem; ``theta`` the Dörfler parameter
    the marking used (raised to grow the mesh, lowered to fit a budget), ``marked`` the
    elements it marked; ``bracket_step`` the step whose mesh gave the U bracket's lower
    bounds at ``F ∓ δ`` (None: this one's).
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
    #: the lower bound used: "global" (the equilibrium-element program) or "local"
    lower: str = "global"
    bracket_step: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def line(self) -> str:
        bracket = "" if math.isnan(self.U_lower) else f"  U in [{self.U_lower:.6g}, {self.U_upper:.6g}]"
        if bracket and self.bracket_step is not None:
            bracket += f" (lower bounds at F ∓ δ of step {self.bracket_step})"
        flag = "" if self.certified else "  (NOT certified)"
        return (f"step {self.step:2d}  {self.n_elements:9,d} elements  lower {self.energy_lower:.8g}  "
                f"upper {self.energy_upper:.8g}  gap {self.gap_rel:.3e}{bracket}  {self.seconds:.1f} s  "
                f"({self.lower} lower bound){flag}")


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

    @property
    def bracket(self) -> "RunBracket":
        """The energy bracket of the whole run (:func:`run_bracket`)."""
        return run_bracket(self.steps)

    def reached(self, rtol: float) -> bool:
        """Whether the last mesh's certified bounds, or the run's certified bracket, are
        within ``rtol``."""
        final, run = self.final, self.bracket
        return bool((final.certified and final.gap_rel <= rtol) or (run.certified and run.gap_rel <= rtol))


@dataclass(frozen=True)
class RunBracket:
    """``lower <= Pi* <= upper`` over a run: the largest lower and the smallest upper bound of
    its certified meshes (``lower_step``, ``upper_step``), ``gap_rel = (upper - lower) / |upper|``."""

    lower: float
    upper: float
    gap_rel: float
    lower_step: int
    upper_step: int
    certified: bool

    def as_dict(self) -> dict[str, Any]:
        """The keys ``summary.json`` gains."""
        return {"run_energy_lower": self.lower, "run_energy_upper": self.upper, "run_gap_rel": self.gap_rel,
                "run_lower_step": self.lower_step, "run_upper_step": self.upper_step,
                "run_bounds_certified": self.certified}

    def tighter_than(self, gap_rel: float) -> bool:
        """Whether the run's bracket is certified and tighter than a mesh's own ``gap_rel``
        (then an earlier mesh's bound is the better one, and the run's bracket is worth saying)."""
        return self.certified and self.gap_rel < gap_rel

    def line(self) -> str:
        return (f"over the run: energy in [{self.lower:.8g}, {self.upper:.8g}], relative gap {self.gap_rel:.3e} "
                f"(lower bound of step {self.lower_step}, upper bound of step {self.upper_step})")


def run_bracket(steps: tuple[Step, ...] | list[Step]) -> RunBracket:
    """The bracket of a run. Every mesh of a run covers the same domain with the same data,
    so each certified mesh's lower and upper bounds bound the same continuum ``Pi*``, and
    the largest lower bound and the smallest upper bound, from whichever meshes, are a
    bracket too. The local lower bound is not monotone along a run (how far its descent gets
    varies from mesh to mesh, and ``adapt --lower auto`` moves from the global program to it),
    so the best lower bound need not be the last mesh's. Without a certified mesh: the last
    mesh's own, not certified. A largest lower bound above the smallest upper bound (beyond
    their round-off, :func:`~elastoplast.bounds.bracket.bracket_holds`) proves that one of
    them is not a bound: not certified either."""
    from elastoplast.bounds.bracket import bracket_holds

    certified = [s for s in steps if s.certified]
    if not certified:
        last = steps[-1]
        return RunBracket(last.energy_lower, last.energy_upper, last.gap_rel, last.step, last.step, False)
    lo = max(certified, key=lambda s: s.energy_lower)
    hi = min(certified, key=lambda s: s.energy_upper)
    gap = hi.energy_upper - lo.energy_lower
    rel = gap / abs(hi.energy_upper) if hi.energy_upper != 0 else math.inf
    return RunBracket(lo.energy_lower, hi.energy_upper, float(rel), lo.step, hi.step,
                      bracket_holds(lo.energy_lower, hi.energy_upper))


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
