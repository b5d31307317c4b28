"""Uzawa with Nesterov/FISTA momentum and adaptive restart (``"uzawa-fast"``).

Uzawa's step (ii) is a projected gradient step on the displacement form (D):
the gradient of ``f(u, U) = sum_T |T| W(B_T u) - F U`` is ``(r, -F)`` with
``r = sum_T |T| B_T^T R(eps(u))``, and in the metric ``G`` (plus ``w`` for U)
it is Lipschitz with constant ``lambda_max(C)``. FISTA (Beck & Teboulle 2009)
takes the same two steps of :mod:`elastoplast.uzawa` at an extrapolated point

    y^k     = x^k + beta_k (x^k - x^{k-1}),   beta_k = (t_{k-1} - 1) / t_k,
    x^{k+1} = P_K[y^k - rho G^{-1} grad f(y^k)]       (steps (i) and (ii) at y^k),

with ``rho = RHO_SHARE / lambda_max(C)`` (FISTA needs ``rho <= 1/L``, half of
plain Uzawa's bound), and restarts the momentum (``t = 1``) whenever the
gradient-mapping test of O'Donoghue & Candes (2015)
``(y^k - x^{k+1}) . (x^{k+1} - x^k) > 0`` (in the metric G) says the momentum
points uphill. The restart recovers the linear rate of strongly convex
problems (H > 0) with a better constant; without it FISTA oscillates.

The iteration stops on the certificate of MATH.md section 6 at the candidate
``(R(eps(x^k)), x^k)``, like plain Uzawa.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from .certificate import certify
from .discretize import nondimensionalize
from .solution import Solution, Status, make_solution
from .uzawa import (
    contact_operators,
    factorize_metric,
    metric_matrix,
    project_contact,
    project_stresses,
    within_tolerance,
)

#: step as a share of FISTA's bound 1 / lambda_max(C)
RHO_SHARE = 0.99


@dataclass(frozen=True)
class FastOptions:
    """Settings of :func:`solve_uzawa_fast`; ``check_every`` iterations between
    certificate evaluations (history rows are written at those)."""

    tol: float = 1e-6
    max_iter: int = 5000
    check_every: int = 5
    restart: bool = True
    factorization: str = "auto"
    progress: bool = False


def metric_inner(nd, a: np.ndarray, b: np.ndarray, aU: float, bU: float, weight: float) -> float:
    """``a^T G b + w aU bU`` with ``G = sum_T |T| B_T^T B_T``."""
    return float(np.sum(nd.volumes[:, None] * nd.strain(a) * nd.strain(b)) + weight * aU * bU)


def solve_uzawa_fast(disc, options: FastOptions = FastOptions()) -> Solution:
    """FISTA with adaptive restart on Uzawa's steps; see the module docstring."""
    t_start = time.perf_counter()
    timings = {"setup": 0.0, "iterations": 0.0, "certificate": 0.0}
    nd, units = nondimensionalize(disc)
    rho = RHO_SHARE / nd.material.max_stiffness_eigenvalue()
    solve = factorize_metric(metric_matrix(nd), options.factorization)
    ops = contact_operators(nd.N, solve)
    zero = np.zeros(nd.n_free)
    x, X, lam = project_contact(zero, 0.0, zero, 0.0, nd.force, nd.N, nd.psi, solve, ops)
    x_old, X_old, t = x.copy(), X, 1.0
    timings["setup"] = time.perf_counter() - t_start

    history: list[dict[str, Any]] = []
    status, message, restarts = Status.MAX_ITERATIONS, "", 0
    n = 0
    while True:
        if n % options.check_every == 0 or n == options.max_iter:
            t0 = time.perf_counter()
            sigma, xi = project_stresses(nd.material, nd.strain(x))
            kkt = certify(nd, sigma, xi, nd.full_displacement(x), X)
            history.append({"iteration": n, "residuals": kkt.as_dict(), "kkt_worst": kkt.worst,
                            "U": X * units.displacement, "restarts": restarts,
                            "time_s": time.perf_counter() - t_start})
            timings["certificate"] += time.perf_counter() - t0
            if options.progress:
                print(f"uzawa-fast {n:5d}  kkt {kkt.worst:.2e}  restarts {restarts}", file=sys.stderr, flush=True)
            if not (np.all(np.isfinite(x)) and np.isfinite(kkt.worst)):
                status, message = Status.DIVERGED, f"non-finite iterate at iteration {n}"
                break
            if within_tolerance(kkt, options.tol):
                status, message = Status.CONVERGED, f"KKT residuals <= {options.tol:g} after {n} iterations"
                break
            if n == options.max_iter:
                message = f"stopped after max_iter = {n} iterations (worst KKT residual {kkt.worst:.3g})"
                break
        t0 = time.perf_counter()
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        beta = (t - 1.0) / t_new
        y, Y = x + beta * (x - x_old), X + beta * (X - X_old)
        s_y, _ = project_stresses(nd.material, nd.strain(y))  # step (i) at y
        x_new, X_new, lam = project_contact(y, Y, nd.internal_force(s_y), rho, nd.force, nd.N, nd.psi,
                                            solve, ops, lam)  # step (ii) from y
        if options.restart and metric_inner(nd, y - x_new, x_new - x, Y - X_new, X_new - X, ops.weight) > 0.0:
            t_new = 1.0
            restarts += 1
        x_old, X_old, x, X, t = x, X, x_new, X_new, t_new
        timings["iterations"] += time.perf_counter() - t0
        n += 1

    timings["total"] = time.perf_counter() - t_start
    return make_solution(
        disc, method="uzawa-fast", status=status, sigma=sigma * units.stress, xi=xi * units.stress,
        u_free=x * units.displacement, U=X * units.displacement, iterations=n, timings=timings,
        message=f"{message} (FISTA, rho = {RHO_SHARE:g}/lambda_max(C), {restarts} restarts)", history=history,
    )


def uzawa_fast_method(disc, tol: float | None = None, max_iter: int | None = None, progress: bool = False,
                      **options: Any) -> Solution:
    """The ``"uzawa-fast"`` entry of the method registry (``rho`` is ignored: the step is fixed by FISTA's bound)."""
    known = set(FastOptions.__dataclass_fields__)
    kw = {k: v for k, v in options.items() if k in known}
    kw.update({k: v for k, v in (("tol", tol), ("max_iter", max_iter)) if v is not None})
    return solve_uzawa_fast(disc, FastOptions(progress=progress, **kw))
