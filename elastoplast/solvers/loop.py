"""The loop every iterative method shares: certify a candidate, record it, decide.

Uzawa, FISTA, ALG2 and Newton differ in how they produce the next candidate
``(sigma, xi, u, U)``; they agree on everything else, which lives here once:

* the candidate is judged by the certificate of docs/certificate.md
  (:func:`~elastoplast.certificate.kkt.certify`), never by a step length;
* the stopping rule (:meth:`Monitor.check`), in this order: non-finite values
  -> DIVERGED; every residual ``<= tol`` -> CONVERGED; the worst residual
  ``divergence_factor`` times above the first one (and above ``tol``) ->
  DIVERGED; ``max_iter`` reached -> MAX_ITERATIONS; ``time_limit`` passed ->
  TIME_LIMIT;
* one history schema (:data:`HISTORY_KEYS`, plus method-specific extras);
* the progress bar;
* the way back from the O(1) units of
  :func:`~elastoplast.fem.discretize.nondimensionalize` to the user's, and the final
  status, which the certificate of the answer in the user's units confirms
  (:meth:`Monitor.solution`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from elastoplast.certificate.kkt import KKTResiduals, certify
from elastoplast.certificate.solution import (
    ACTIVE_FORCE_SHARE,
    PLASTIC_SHARE,
    Solution,
    Status,
    make_solution,
)
from elastoplast.errors import expect
from elastoplast.fem.discretize import Discretization, Units
from elastoplast.fem.material import von_mises
from elastoplast.options import SolverOptions

#: the keys of every history row (methods may add their own after these)
HISTORY_KEYS = ("iteration", "residuals", "kkt_worst", "U", "n_active", "n_plastic", "time_s")

#: a worst residual this many times above the first one means divergence
DIVERGENCE_FACTOR = 1e8


def check_inputs(disc: Any, options: Any, kind: type[SolverOptions]) -> Any:
    """The checks at the top of every ``solve_*``, before any work: ``disc`` a
    :class:`~elastoplast.fem.discretize.Discretization`, ``options`` an instance of
    ``kind``, a mapping of its options or ``None`` (the defaults), each refused
    naming the argument (:meth:`~elastoplast.options.SolverOptions.of`). Returns
    the options as a ``kind``."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    return kind.of(options, "options")


def within_tolerance(kkt: KKTResiduals, tol: float) -> bool:
    """Every certificate residual ``|r_i| / s_i <= tol`` (NaN fails).

    The certificate already divides each residual by its stated scale ``s_i``
    (see :class:`~elastoplast.certificate.kkt.KKTResiduals`), so this is the test
    ``|r_i| <= eps_abs + eps_rel * s_i`` with ``eps_rel = tol`` and
    ``eps_abs = 0``: the residuals carry different units (stress, force,
    length), so no single absolute floor would mean anything.
    """
    return all(value <= tol for value in kkt.as_dict().values())


@dataclass(frozen=True)
class Verdict:
    """Why an iteration stops."""

    status: Status
    message: str


class Monitor:
    """Certificate-based stopping and the history of one iterative run.

    ``nd``/``units`` are the scaled problem the method iterates on and the way
    back; ``label`` names the method in the progress bar and the answer.
    """

    def __init__(self, label: str, disc: Discretization, nd: Discretization, units: Units, options: SolverOptions,
                 *, divergence_factor: float = DIVERGENCE_FACTOR, t_start: float | None = None):
        from tqdm.auto import tqdm

        self.label, self.disc, self.nd, self.units, self.options = label, disc, nd, units, options
        self.divergence_factor = divergence_factor
        self.t_start = time.perf_counter() if t_start is None else t_start
        self.history: list[dict[str, Any]] = []
        self.first_worst: float | None = None
        self.last: KKTResiduals | None = None
        self.bar = tqdm(total=options.max_iter, disable=not options.progress, desc=label, unit="it", leave=False)

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t_start

    def check(self, n: int, sigma: np.ndarray, xi: np.ndarray, u: np.ndarray, U: float, *,
              tol: float | None = None, nd: Discretization | None = None, internal_force: np.ndarray | None = None,
              **extra: Any) -> Verdict | None:
        """Certify the candidate of iteration ``n`` (scaled units, ``u`` on the
        free dofs), append a history row and say whether to stop (``None``: go on).

        ``tol`` and ``nd`` override the options' tolerance and the scaled
        problem (intermediate load steps certify at their own force).
        ``internal_force``: ``nd.internal_force(sigma)`` when the caller has it
        (the history's active count only; the certificate computes its own).
        """
        nd = self.nd if nd is None else nd
        tol = self.options.tol if tol is None else tol
        finite = bool(np.all(np.isfinite(u)) and math.isfinite(U) and np.all(np.isfinite(sigma)))
        kkt = certify(nd, sigma, xi, nd.full_displacement(u), U)
        self.last = kkt
        worst = kkt.worst
        if not finite:
            r = np.full(nd.n_free, np.nan)
        else:
            r = nd.internal_force(sigma) if internal_force is None else internal_force
        lam = nd.N @ r
        row = {
            "iteration": int(n), "residuals": kkt.as_dict(), "kkt_worst": worst, "U": float(U) * self.units.displacement,
            "n_active": int(np.sum(lam > ACTIVE_FORCE_SHARE * max(np.nanmax(lam, initial=0.0), 0.0))),
            "n_plastic": int(np.sum(von_mises(sigma) >= PLASTIC_SHARE * (nd.material.yield_stress + xi))),
            "time_s": self.elapsed, **extra,
        }
        self.history.append(row)
        if self.first_worst is None and math.isfinite(worst):
            self.first_worst = worst
        self.bar.n = min(int(n), self.bar.total)
        self.bar.set_postfix(kkt=f"{worst:.1e}", U=f"{row['U']:.5g}", refresh=True)
        if not (finite and math.isfinite(worst)):
            return Verdict(Status.DIVERGED, f"non-finite iterate at iteration {n}")
        if within_tolerance(kkt, tol):
            return Verdict(Status.CONVERGED, f"KKT residuals <= {tol:g} after {n} iterations")
        if worst > self.divergence_factor * max(self.first_worst, tol):
            return Verdict(Status.DIVERGED, f"KKT residual {worst:.3g} grew from {self.first_worst:.3g}")
        if n >= self.options.max_iter:
            return Verdict(Status.MAX_ITERATIONS,
                           f"stopped after max_iter = {n} iterations (worst KKT residual {worst:.3g} > tol {tol:g})")
        limit = self.options.time_limit
        if limit is not None and self.elapsed >= limit:
            return Verdict(Status.TIME_LIMIT, f"stopped by time_limit = {limit:g} s after {n} iterations "
                                              f"(worst KKT residual {worst:.3g} > tol {tol:g})")
        return None

    def solution(self, verdict: Verdict, sigma: np.ndarray, xi: np.ndarray, u: np.ndarray, U: float, *,
                 iterations: int, timings: dict[str, float], note: str = "",
                 contact_force: np.ndarray | None = None) -> Solution:
        """The answer in the user's units, certified there.

        CONVERGED stands only if the certificate of the answer in the user's
        units passes too (it is the same relative test; this guards round-off
        and any method-specific shortcut). ``note`` is appended to the message.
        """
        self.bar.close()
        s = self.units
        timings = {**timings, "total": self.elapsed}
        message = verdict.message + (f" ({note})" if note else "")
        with np.errstate(all="ignore"):  # a diverged candidate is certified as it is: NaN, without warnings
            sol = make_solution(
                self.disc, method=self.label, status=verdict.status, sigma=sigma * s.stress, xi=xi * s.stress,
                u_free=u * s.displacement, U=U * s.displacement,
                contact_force=None if contact_force is None else contact_force * s.force,
                iterations=iterations, timings=timings, message=message, history=self.history,
            )
        return confirm(sol, self.options.tol)


def confirm(sol: Solution, tol: float) -> Solution:
    """Downgrade a CONVERGED answer whose own certificate does not pass ``tol``."""
    from dataclasses import replace

    if sol.status is Status.CONVERGED and not within_tolerance(sol.kkt, tol):
        return replace(sol, status=Status.FAILED,
                       message=f"{sol.message}; but the answer's certificate, worst residual {sol.kkt.worst:.2e}, "
                               f"is above tol {tol:g}")
    return sol
