"""Accelerated dual methods (``"uzawa-fast"``): FISTA with adaptive restart (default) and ALG2.

Uzawa's step (ii) is a projected gradient step on the displacement form (D):
the gradient of ``f(u, U) = sum_T |T| W(B_T u) - F U`` is ``(r, -F)`` with
``r = sum_T |T| B_T^T R(eps(u))``, and in the metric ``G`` (plus ``w`` for U)
it is Lipschitz with constant ``lambda_max(C)``. FISTA (Beck & Teboulle 2009)
takes the same two steps of :mod:`elastoplast.solvers.uzawa` at an extrapolated point

    y^k     = x^k + beta_k (x^k - x^{k-1}),   beta_k = (t_{k-1} - 1) / t_k,
    x^{k+1} = P_K[y^k - rho G^{-1} grad f(y^k)]       (steps (i) and (ii) at y^k),

with ``rho = RHO_SHARE / lambda_max(C)`` (FISTA needs ``rho <= 1/L``, half of
plain Uzawa's bound), and restarts the momentum (``t = 1``) whenever the
gradient-mapping test of O'Donoghue & Candes (2015)
``(y^k - x^{k+1}) . (x^{k+1} - x^k) > 0`` (in the metric G) says the momentum
points uphill. The restart recovers the linear rate of strongly convex
problems (H > 0) with a better constant; without it FISTA oscillates.

The iteration stops on the certificate of docs/certificate.md at the candidate
``(R(eps(x^k)), x^k)``, like plain Uzawa.

ALG2 (Fortin & Glowinski), ``FastOptions(variant="alg2")``, splits ``q = eps(v)``
in form (D) with the condensed plastic energy W (gradient R) and iterates on
``L_r = sum |T| [W(q) + sigma.(eps(v) - q) + r/2 |eps(v) - q|_M^2] - F V``:
(1) ``(v, V)`` minimises L_r over K_h, a contact projection in the metric
``G_M = sum |T| B^T M B`` (:func:`alg2_displacements`, Uzawa's step (ii));
(2) ``q`` minimises ``W(q) + r/2 |q - eps(v) - M^{-1} sigma / r|_M^2``, a return
mapping with modified moduli (:func:`prox_energy`); (3) ``sigma += r M (eps(v) - q)``.
M = C (``splitting="stiffness"``, G_M the elastic stiffness, r dimensionless)
took fewer iterations than M = I at every penalty measured; the candidate
``(R(eps(v)), v, V)`` reached the tolerance 5-25 iterations before the
multiplier sigma itself or the exactly equilibrated ``sigma + r M (eps - q_old)``
(cylinder_2d 40x20, H = E/1000). Residual balancing of r (Boyd et al.) was
tried and made it slower: it raised r where the plastic zone wants it lower.

Why FISTA is the default (benchmarks/methods/accelerated.md, one run, 27 cases:
cylinder_2d 80x40, sphere quarter 8x8x8 and block 16x16x8, H = E/10, E/100,
E/1000, forces F, 3F, 6F; wall time to KKT <= 1e-8): ALG2's best penalty moves
with the size of the plastic zone, from 0.7 C down to 0.15 C. At r = 0.4 C,
the best single value, ALG2 takes 0.88 of FISTA's time (geometric mean) and
wins 18 of 27 cases, but needs 460 iterations (1.14 s) against FISTA's 295
(0.70 s) on the hardest case (2D, 6F, H = E/1000, 3,016 plastic elements), the
regime acceleration is for. At r = 0.25 C it ties there (0.64 s) and loses the
gain elsewhere (geometric mean 1.01, same total time). No single r beats
FISTA in both regimes by more than the run-to-run noise, and FISTA has no
parameter to tune, so it stays the default; ALG2 remains selectable.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from elastoplast.certificate.solution import Solution, check_solution
from elastoplast.errors import InputError
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.fem.material import Material, Prestate, n_components, return_mapping
from elastoplast.linalg.direct import FACTORIZATIONS
from elastoplast.options import MAX_ITER_CEILING, SolverOptions, option
from elastoplast.solvers.contact import (
    iterative_context,
    metric_projection,
    projection_note,
)
from elastoplast.solvers.loop import Monitor, check_inputs
from elastoplast.solvers.uzawa import project_stresses

#: step as a share of FISTA's bound 1 / lambda_max(C)
RHO_SHARE = 0.99
#: ALG2's penalty r per splitting, in the scaled units (E = 1; for "stiffness" r is a
#: multiple of C). Measured (benchmarks/methods/accelerated.md, part 1): the best r
#: moves from 0.7 (small plastic zones) down to 0.15-0.25 (2D at 6F, H <= E/100);
#: 0.4 is the best single value over the 27 cases of part 2 (geometric mean).
DEFAULT_PENALTY = {"stiffness": 0.4, "identity": 0.6}
#: admitted penalty r (units of E): the best measured lie in 0.15..0.7, and 1e-8 and 1e8 still
#: iterate without overflow (stalling); 1e-300 overflowed to inf within five iterations
PENALTY_RANGE = (1e-8, 1e8)


@dataclass(frozen=True)
class FastOptions(SolverOptions):
    """Settings of :func:`solve_uzawa_fast` and :func:`solve_alg2` (``tol``,
    ``max_iter``, ``time_limit``, ``progress``:
    :class:`~elastoplast.options.SolverOptions`). The step is fixed by FISTA's
    bound (:data:`RHO_SHARE`), so there is no ``rho``."""

    max_iter: int = option(5000, int, "iteration limit", lo=1, hi=MAX_ITER_CEILING)
    check_every: int = option(5, int, "iterations between certificate checks", lo=1, hi=MAX_ITER_CEILING)
    restart: bool = option(True, bool, "adaptive restart of the momentum (FISTA)")
    factorization: str = option("auto", str, "sparse factorisation of the metric, or amg (iterative)",
                                choices=("auto", *FACTORIZATIONS, "amg"))
    inner_rtol: float = option(1e-2, float, "amg: relative residual of each face solve of step (ii)",
                               lo=1e-14, hi=1e-1)
    variant: str = option("fista", str, "the accelerated method", choices=("fista", "alg2"))
    splitting: str = option("stiffness", str, "ALG2 only: the metric M of the penalty (M = C or I)",
                            choices=("stiffness", "identity"))
    penalty: float | None = option(None, float, "ALG2 only: the penalty r in units of E (none: automatic)",
                                   lo=PENALTY_RANGE[0], hi=PENALTY_RANGE[1], none=True)
    initial: Solution | None = option(None, Solution, "warm start: a Solution of the same discretisation (u, U)",
                                      none=True, persist=False)


def alg2_penalty(material: Material, options: "FastOptions") -> float:
    """The penalty r in the scaled units (E = 1): as given, or :data:`DEFAULT_PENALTY`."""
    if options.splitting not in DEFAULT_PENALTY:
        raise InputError("splitting", f"must be one of {sorted(DEFAULT_PENALTY)}, got {options.splitting!r}")
    r = DEFAULT_PENALTY[options.splitting] if options.penalty is None else options.penalty
    if not (isinstance(r, (int, float)) and np.isfinite(r) and r > 0):
        raise InputError("penalty", f"must be a number > 0, got {r!r}")
    return float(r)


def metric_inner(nd, a: np.ndarray, b: np.ndarray, aU: float, bU: float, weight: float) -> float:
    """``a^T G b + w aU bU`` with ``G = sum_T |T| B_T^T B_T``."""
    return float(np.sum(nd.volumes[:, None] * nd.strain(a) * nd.strain(b)) + weight * aU * bU)


def strain_inner(nd, ea: np.ndarray, eb: np.ndarray, aU: float, bU: float, weight: float,
                 overwrite: bool = False) -> float:
    """:func:`metric_inner` of ``a``, ``b`` given their strains ``ea = B a``, ``eb = B b``;
    ``overwrite``: ``ea`` is a work array that may hold the products (no temporaries; the
    same products in the same order)."""
    if overwrite:
        prod = np.multiply(ea, nd.volumes[:, None], out=ea)
        prod *= eb
    else:
        prod = nd.volumes[:, None] * ea * eb
    return float(np.sum(prod) + weight * aU * bU)


# ----------------------------------------------------------------------------
# ALG2: the augmented Lagrangian of the splitting q = eps(v)
# ----------------------------------------------------------------------------


def splitting_metric(material: Material, dim: int, splitting: str) -> np.ndarray:
    """The metric M of the penalty ``r/2 |eps - q|_M^2``: I, or C (``"stiffness"``)."""
    if splitting == "identity":
        return np.eye(n_components(dim))
    if splitting == "stiffness":
        return material.stiffness(dim)
    raise InputError("splitting", f"must be 'identity' or 'stiffness', got {splitting!r}")


def prox_material(material: Material, r: float, splitting: str) -> Material:
    """The material whose return mapping is the proximal map of W (:func:`prox_energy`).

    Minimising ``1/2 (q - p) C (q - p) + r/2 |q - z|_M^2`` over q leaves
    ``1/2 (z - p) C_r (z - p)`` with the series stiffness
    ``C_r = (C^{-1} + M^{-1} / r)^{-1}``, isotropic again:
    M = I: ``2 mu' = 2 mu r / (2 mu + r)``, ``3 K' = 3 K r / (3 K + r)``;
    M = C: ``C_r = r / (1 + r) C`` (both moduli scaled). Yield stress and H are
    unchanged.
    """
    mu, K = material.mu, material.bulk
    if splitting == "identity":
        mu_r, K_r = mu * r / (2.0 * mu + r), K * r / (3.0 * K + r)
    else:
        mu_r, K_r = mu * r / (1.0 + r), K * r / (1.0 + r)
    E_r = 9.0 * K_r * mu_r / (3.0 * K_r + mu_r)
    nu_r = (3.0 * K_r - 2.0 * mu_r) / (2.0 * (3.0 * K_r + mu_r))
    return Material(E_r, nu_r, material.yield_stress, material.hardening)


def prox_energy(material: Material, z: np.ndarray, r: float, splitting: str = "identity",
                M_inv: np.ndarray | None = None,
                state: Prestate | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ALG2's step (2): ``q = argmin_q W(q) + r/2 |q - z|_M^2`` per row of ``z``.

    ``W(e) = min_p 1/2 (e - p) C (e - p) + sigma_y kappa + 1/2 H kappa^2`` is the
    condensed plastic energy (its gradient is the return mapping R). Minimising
    jointly over q and the plastic strain p, the minimum over q for fixed p is a
    quadratic in ``z - p`` with the series stiffness of :func:`prox_material`;
    the minimum over p is then the return mapping ``R_r`` of that material at
    z. Stationarity in q, ``R(q) + r M (q - z) = 0``, gives

        sigma' = R_r(z),   q = z - M^{-1} sigma' / r,   R(q) = sigma'.

    Returns ``(q, sigma', xi')``: the minimiser, and the stress and hardening
    stress of the real material at q.

    On a step from a ``state``, ``W_n(q)`` is Hencky's W at ``q + A sigma_n`` with
    the yield stress ``sigma_y + xi_n`` (up to a constant), so the same formulas
    hold with ``R_r`` shifted by the state's elastic strain (the real material's
    ``A sigma_n``, kept by the state).
    """
    mat_r = prox_material(material, r, splitting)
    sigma, xi, _ = return_mapping(mat_r, z, state)
    if M_inv is None:
        dim = 2 if z.shape[-1] == 4 else 3
        M_inv = np.linalg.inv(splitting_metric(material, dim, splitting))
    return z - (sigma @ M_inv) / r, sigma, xi


@dataclass(frozen=True)
class ALG2Step:
    """What one ALG2 iteration needs: the contact projection in the metric
    ``G_M = sum_T |T| B_T^T M B_T`` (:func:`~elastoplast.solvers.uzawa.metric_projection`),
    M and its inverse and the penalty r."""

    project: object
    M: np.ndarray
    M_inv: np.ndarray
    r: float
    splitting: str


def alg2_setup(nd, r: float, splitting: str, factorization: str = "auto", length: float = 1.0,
               inner_rtol: float = 1e-6) -> ALG2Step:
    """Factor ``G_M`` once, or set up its iterative solves (M = I: Uzawa's
    metric G; M = C: the elastic stiffness K); ``length`` is the unit of the
    scaled ``nd`` (:func:`~elastoplast.linalg.blocks.block_layout`)."""
    M = splitting_metric(nd.material, nd.dim, splitting)
    return ALG2Step(project=metric_projection(nd, length, M, factorization, None, inner_rtol), M=M,
                    M_inv=np.linalg.inv(M), r=r, splitting=splitting)


def alg2_displacements(nd, step: ALG2Step, q: np.ndarray, sigma: np.ndarray, V: float,
                       lam: np.ndarray | None, v: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """ALG2's step (1): ``(v, V)`` minimises ``r/2 sum |T| |eps(v) - q + M^{-1} sigma / r|_M^2 - F V``
    over K_h, plus the proximal term ``r w / 2 (V - V^n)^2`` (w: the weight of
    :func:`~elastoplast.solvers.uzawa.contact_operators`).

    Divided by r this is ``1/2 |v - v*|_{G_M}^2 + w/2 (V - V^n)^2 - (F / r) V``
    with ``G_M v* = b / r``, ``b = sum_T |T| B_T^T (r M q_T - sigma_T)``: exactly
    Uzawa's step (ii) (:func:`~elastoplast.solvers.uzawa.project_contact`) from
    ``u = 0`` with gradient ``-b`` and step ``1 / r``. Without the proximal
    term V would enter only linearly and be fixed by the contact constraints
    alone (``V = min(N v + psi)``, a QP with the equality ``sum lam = F``);
    the small proximal term (w is a tenth of the contact compliance) keeps the
    bound-constrained QP of Uzawa and makes this the semi-proximal ALG2, whose
    fixed points are those of ALG2. The contact forces are ``r lam``. ``v``,
    the last iterate, is where an iterative projection starts (its face solves
    are then for the change, which vanishes as ALG2 converges).
    """
    b = nd.internal_force(step.r * (q @ step.M) - sigma)
    return step.project(np.zeros(nd.n_free), V, -b, 1.0 / step.r, nd.force, nd.N, nd.psi, lam,
                        start=None if v is None else (v, V))


def solve_uzawa_fast(disc, options: FastOptions = FastOptions()) -> Solution:
    """FISTA with adaptive restart on Uzawa's steps; see the module docstring.
    ``options``: :class:`FastOptions`, a mapping of them or ``None``."""
    options = check_inputs(disc, options, FastOptions)
    with np.errstate(all="ignore"):  # a non-finite iterate is the monitor's DIVERGED, not a warning
        return _solve_uzawa_fast(disc, options)


def start_run(disc, options: FastOptions):
    """What both variants start with: ``(t_start, timings, nd, units, monitor)``."""
    t_start = time.perf_counter()
    nd, units = nondimensionalize(disc)
    monitor = Monitor("uzawa-fast", disc, nd, units, options, t_start=t_start)
    return t_start, {"setup": 0.0, "iterations": 0.0, "certificate": 0.0}, nd, units, monitor


def _solve_uzawa_fast(disc, options: FastOptions) -> Solution:
    t_start, timings, nd, units, monitor = start_run(disc, options)
    rho = RHO_SHARE / nd.material.max_stiffness_eigenvalue()
    proj = metric_projection(nd, units.length, np.eye(nd.k), options.factorization, None, options.inner_rtol)
    zero = np.zeros(nd.n_free)
    x, X, lam = proj(*initial_point(disc, units, options, zero), zero, 0.0, nd.force, nd.N, nd.psi)
    x_old, X_old, t = x.copy(), X, 1.0
    # the strains of the iterates, one product B x per iteration: those of y and of the
    # restart test's differences are their linear combinations (B is linear), which saves
    # two of the three products of an iteration and the one of each check (measured at
    # 118k tetrahedra: 0.7 s of products in 40 iterations, of an 18 s run)
    e_x = nd.strain(x)
    e_old = e_x
    # two element-sized work arrays for e_y and the restart test's differences, written in
    # place: the same operations in the same order as the expressions they replace
    # (``e_x + beta (e_x - e_old)``, ``sum |T| (e_y - e_new)(e_new - e_x)``), without four
    # fresh (n_el, k) temporaries an iteration (49 MB each at 1.03M tetrahedra)
    work = [np.empty_like(e_x), np.empty_like(e_x)]
    timings["setup"] = time.perf_counter() - t_start

    restarts, n = 0, 0
    while True:
        if n % options.check_every == 0 or n >= options.max_iter:
            t0 = time.perf_counter()
            sigma, xi = project_stresses(nd.material, e_x, nd.state)
            verdict = monitor.check(n, sigma, xi, x, X, restarts=restarts)
            timings["certificate"] += time.perf_counter() - t0
            if verdict is not None:
                break
        t0 = time.perf_counter()
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        beta = (t - 1.0) / t_new
        y, Y = x + beta * (x - x_old), X + beta * (X - X_old)
        e_y = np.subtract(e_x, e_old, out=work[0])
        e_y *= beta
        e_y += e_x
        s_y, _ = project_stresses(nd.material, e_y, nd.state)  # step (i) at y
        x_new, X_new, lam = proj(y, Y, nd.internal_force(s_y), rho, nd.force, nd.N, nd.psi, lam)  # step (ii) from y
        e_new = nd.strain(x_new)
        if options.restart and strain_inner(nd, np.subtract(e_y, e_new, out=e_y), np.subtract(e_new, e_x, out=work[1]),
                                            Y - X_new, X_new - X, proj.weight, overwrite=True) > 0.0:
            t_new = 1.0
            restarts += 1
        x_old, X_old, x, X, t = x, X, x_new, X_new, t_new
        # e_old's array (not the start's, which e_x still is at the first iteration) is free now
        if e_old is not e_x:
            work[1] = e_old
        e_old, e_x = e_x, e_new
        timings["iterations"] += time.perf_counter() - t0
        n += 1
    return monitor.solution(verdict, sigma, xi, x, X, iterations=n, timings=timings,
                            note=f"FISTA, rho = {RHO_SHARE:g}/lambda_max(C), {restarts} restarts{projection_note(proj)}")


def solve_alg2(disc, options: FastOptions = FastOptions()) -> Solution:
    """ALG2 (Fortin & Glowinski) on the displacement form; see the module docstring.

    Iteration n: step (1) :func:`alg2_displacements`, step (2)
    :func:`prox_energy` at ``z = eps(v) + M^{-1} sigma / r``, step (3)
    ``sigma <- sigma + r M (eps(v) - q)``, which equals ``R(q)`` (returned by
    step (2)). The certificate judges ``(R(eps(v)), v, V)``, like Uzawa's.
    ``options``: :class:`FastOptions`, a mapping of them or ``None``.
    """
    options = check_inputs(disc, options, FastOptions)
    with np.errstate(all="ignore"):  # a non-finite iterate is the monitor's DIVERGED, not a warning
        return _solve_alg2(disc, options)


def _solve_alg2(disc, options: FastOptions) -> Solution:
    t_start, timings, nd, units, monitor = start_run(disc, options)
    r = alg2_penalty(nd.material, options)
    step = alg2_setup(nd, r, options.splitting, options.factorization, units.length, options.inner_rtol)
    zero = np.zeros(nd.n_free)
    v, V, lam = step.project(*initial_point(disc, units, options, zero), zero, 0.0, nd.force, nd.N, nd.psi)
    q = nd.strain(v)
    sigma, xi = project_stresses(nd.material, q, nd.state)
    timings["setup"] = time.perf_counter() - t_start

    n = 0
    while True:
        if n % options.check_every == 0 or n >= options.max_iter:
            t0 = time.perf_counter()
            s_c, x_c = project_stresses(nd.material, nd.strain(v), nd.state)
            verdict = monitor.check(n, s_c, x_c, v, V)
            timings["certificate"] += time.perf_counter() - t0
            if verdict is not None:
                break
        t0 = time.perf_counter()
        v, V, lam = alg2_displacements(nd, step, q, sigma, V, lam, v)  # step (1)
        eps = nd.strain(v)
        q, sigma, xi = prox_energy(nd.material, eps + (sigma @ step.M_inv) / r, r, options.splitting,
                                   step.M_inv, nd.state)  # steps (2) and (3)
        timings["iterations"] += time.perf_counter() - t0
        n += 1
    return monitor.solution(verdict, s_c, x_c, v, V, iterations=n, timings=timings,
                            note=f"ALG2, {options.splitting} splitting, r = {r:g} in units of E"
                                 f"{projection_note(step.project)}")


def initial_point(disc, units, options: FastOptions, zero: np.ndarray) -> tuple[np.ndarray, float]:
    """``(u, U)`` in scaled units to start from: zero, or ``options.initial``'s (the
    first projection onto K_h makes either feasible)."""
    if options.initial is None:
        return zero, 0.0
    return disc.free_displacement(options.initial.u) / units.displacement, options.initial.U / units.displacement


def solve_accelerated(disc, options: FastOptions = FastOptions()) -> Solution:
    """The ``"uzawa-fast"`` method: FISTA (default) or ALG2 as ``options.variant`` says."""
    options = check_inputs(disc, options, FastOptions)
    if options.initial is not None:
        check_solution(disc, options.initial, "initial", reads=("u",), start=True)
    with iterative_context(disc, options.factorization):
        return VARIANTS[options.variant](disc, options)


#: the two accelerated dual methods behind ``"uzawa-fast"``
VARIANTS = {"fista": solve_uzawa_fast, "alg2": solve_alg2}
