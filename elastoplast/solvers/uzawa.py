"""Uzawa's method of the paper (docs/methods.md): two projections per iteration.

Starting from ``(u^0, U^0)`` in K_h, iteration n does

* step (i), :func:`project_stresses`: ``sigma_hat^{n+1} = R(eps(u^n))``, the
  closed-form return mapping element by element (the projection onto P_h);
* step (ii), :func:`project_contact`: ``(u^{n+1}, U^{n+1})`` minimises
  ``1/2 |eps(v - u^n)|^2 + 1/2 (V - U^n)^2 + rho (sigma^{n+1}, eps(v)) - rho F V``
  over K_h, a projected gradient step in the metric ``G = sum_T |T| B_T^T B_T``
  (plus 1 for V). G is factored once (:func:`factorize_spd`); the
  projection is a small QP in the contact multipliers (:func:`solve_contact_qp`).
  On large meshes (:class:`IterativeProjection`) G is never factored: the
  projection is solved in the primal variables by an active-set method whose
  face systems go to AMG-preconditioned CG.

The iteration stops on the KKT residuals of the certificate (docs/certificate.md)
evaluated at the candidate ``(R(eps(u^n)), u^n, U^n)``, never on the step length.
Every function works on plain arrays and a factor so that accelerated variants
can reuse the steps. The loop runs in the O(1) units of
:func:`~elastoplast.fem.discretize.nondimensionalize`; the answer is certified in the
user's units by :func:`~elastoplast.certificate.solution.make_solution`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from elastoplast.certificate.solution import Solution, check_solution
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization, Units, nondimensionalize
from elastoplast.fem.material import Material, Prestate, return_mapping
from elastoplast.linalg.direct import FACTORIZATIONS
from elastoplast.options import MAX_ITER_CEILING, SolverOptions, option
from elastoplast.errors import short_repr
from elastoplast.solvers.contact import (
    CONTACT_QP,
    iterative_context,
    metric_projection,
    projection_note,
)
from elastoplast.solvers.loop import DIVERGENCE_FACTOR, Monitor, check_inputs

# ----------------------------------------------------------------------------
# the step rho
# ----------------------------------------------------------------------------


def rho_bound(material: Material) -> float:
    """The paper's convergence bound ``2 / lambda_max(C)`` (docs/methods.md)."""
    return 2.0 / material.max_stiffness_eigenvalue()


#: default step as a share of the bound 2 / lambda_max(C); the rho sweep of
#: benchmarks/uzawa (REPORT.md) found the iteration count falling monotonically
#: up to the bound, on 2D and 3D problems, elastic-dominated and plastic alike
DEFAULT_RHO_SHARE = 0.95


def default_rho(material: Material) -> float:
    """``DEFAULT_RHO_SHARE * 2 / lambda_max(C)``: safely inside the convergence bound."""
    return DEFAULT_RHO_SHARE * rho_bound(material)


def check_rho(rho: float, material: Material, field: str = "rho") -> float:
    """Refuse a step outside ``(0, 2 / lambda_max(C))``."""
    bound = rho_bound(material)
    if not (isinstance(rho, (int, float)) and np.isfinite(rho) and 0.0 < rho < bound):
        raise InputError(
            field,
            f"must lie in (0, 2/lambda_max(C)) = (0, {bound:.6g}) for Uzawa to converge "
            f"(lambda_max(C) = max(3K, 2mu) = {material.max_stiffness_eigenvalue():.6g}); got {rho!r}",
        )
    return float(rho)


# ----------------------------------------------------------------------------
# the metric G and its factorisation
# ----------------------------------------------------------------------------


def metric_matrix(disc: Discretization) -> sp.csc_matrix:
    """``G = sum_T |T| B_T^T B_T`` on the free dofs, so ``|eps(v)|^2 = v^T G v``."""
    return disc.weighted_gram(np.eye(disc.k)).tocsc()


#: admitted ``rigid_weight``, in the problem's units: on the 2D cylinder (20 x 10) 1e-6 and 1
#: converge in 20 and 49 iterations, 1e-12 and 1e6 stop at max_iter; beyond these bounds the
#: metric's V term is lost to round-off (and 1/w overflows below about 1e-308)
RIGID_WEIGHT_RANGE = (1e-12, 1e12)


@dataclass(frozen=True)
class UzawaOptions(SolverOptions):
    """Settings of :func:`solve_uzawa` (``tol``, ``max_iter``, ``time_limit``,
    ``progress``: :class:`~elastoplast.options.SolverOptions`).

    ``rho``: the step, in 1/stress (``None``: :func:`default_rho`); it must lie
    in ``(0, 2 / lambda_max(C))``, checked against the material at solve time.
    ``check_every``: iterations between certificate evaluations, history rows
    are written at those; ``None`` picks it from the measured cost of one
    certificate against one iteration so that checking costs about a tenth
    of the run (:data:`CHECK_SHARE`), checking sooner when the residuals' decay
    predicts convergence (:func:`_next_check`). ``initial``: warm start from a previous solution of
    the same discretisation (any force). ``factorization``: a key of
    :data:`FACTORIZATIONS`, ``"amg"`` (step (ii) without factorisation:
    :class:`IterativeProjection`) or ``"auto"`` (AMG from
    :data:`UZAWA_AMG_FROM_ELEMENTS` elements on). ``inner_rtol`` (AMG only): the
    relative residual of each face solve of step (ii), relative to a
    right-hand side that vanishes at the fixed point. ``rigid_weight``: see
    :func:`contact_operators`. ``contact_qp``: the dual QP of the direct step (ii),
    ``"active-set"`` (:func:`solve_contact_qp`, the default) or ``"osqp"``.
    """

    max_iter: int = option(5000, int, "iteration limit", lo=1, hi=MAX_ITER_CEILING)
    rho: float | None = option(None, float, "step in 1/stress (none: 0.95 * 2/lambda_max(C))", lo=0.0, lo_open=True,
                               none=True)
    check_every: int | None = option(None, int, "iterations between certificate checks (none: automatic)", lo=1,
                                     hi=MAX_ITER_CEILING, none=True)
    initial: Solution | None = option(None, Solution, "warm start: a Solution of the same discretisation", none=True,
                                      persist=False)
    factorization: str = option("auto", str, "sparse factorisation of the metric G, or amg (iterative)",
                                choices=("auto", *FACTORIZATIONS, "amg"))
    inner_rtol: float = option(1e-2, float, "amg: relative residual of each face solve of step (ii)",
                               lo=1e-14, hi=1e-1)
    #: weight w of the rigid body's displacement in the metric ``|eps(v)|^2 + w V^2``,
    #: in the problem's units (length^(d-2)); None: automatic (:func:`contact_operators`);
    #: 1.0 is the paper's literal metric
    rigid_weight: float | None = option(None, float, "weight of V in the metric (none: automatic)",
                                        lo=RIGID_WEIGHT_RANGE[0], hi=RIGID_WEIGHT_RANGE[1], none=True)
    #: 1 at least: below, the first residual itself would count as divergence
    divergence_factor: float = option(DIVERGENCE_FACTOR, float, "a residual this many times above the first "
                                      "one means divergence", lo=1.0)
    max_check_interval: int = option(10, int, "most iterations between checks when check_every is automatic",
                                     lo=1, hi=1000)
    #: the dual QP of the direct step (ii): the exact active-set method, or OSQP
    #: (:class:`~elastoplast.solvers.contact.OSQPContactQP`, set up once, polished);
    #: the iterative step (ii) has no dual QP and refuses "osqp"
    contact_qp: str = option("active-set", str, "direct step (ii)'s contact QP: active-set (exact) or osqp",
                             choices=CONTACT_QP)


# ----------------------------------------------------------------------------
# step (i): projection onto P_h
# ----------------------------------------------------------------------------


def project_stresses(material: Material, eps: np.ndarray, state: Prestate | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Step (i): ``sigma_hat^{n+1} = R(eps(u^n))`` element by element.

    R is the closed-form projection of ``(C eps, 0)`` onto the admissible set D
    in the energy metric (docs/certificate.md); ``eps`` has shape ``(n_el, k)``.
    On a step of a loading path, R_n from the step's ``state``.
    """
    sigma, xi, _ = return_mapping(material, eps, state)
    return sigma, xi


# ----------------------------------------------------------------------------
# step (ii): projection onto K_h
# ----------------------------------------------------------------------------


# ----------------------------------------------------------------------------
# the loop
# ----------------------------------------------------------------------------


def _initial_point(disc: Discretization, nd: Discretization, units: Units, options: UzawaOptions, rho_nd: float):
    """``(u, U, lam)`` in scaled units: zero, or the warm start's values."""
    init = options.initial  # checked against disc by solve_uzawa
    if init is None:
        return np.zeros(nd.n_free), 0.0, None
    u = disc.free_displacement(init.u) / units.displacement
    lam = rho_nd * np.maximum(init.contact_force, 0.0) / units.force
    return u, init.U / units.displacement, lam


#: what to do with a solution Uzawa cannot start from
WARM_START_ADVICE = ("Uzawa's warm start reads the contact forces too: give a Solution of this discretisation "
                     "(any force), or warm-start solve_newton from one interpolated with ep.prolong_p1")


#: the share of the run the automatic checks aim at. The first value, a quarter, measured
#: on the default 3D problem (Uzawa to KKT 1e-8, AMG path): the interval came out at 1 (the
#: first iteration, which carried an AMG set-up, was the yardstick), a check every
#: iteration, 27% of the run at 118k tetrahedra and 24% at 1.03M. A tenth, with the mean
#: iteration from the second on as yardstick and the checks placed by :func:`_next_check`:
#: 9 checks instead of 41 at 118k (certificate 1.2 of 14.1 s, was 5.2 of 18.4 s) and
#: 6.6 of 68.1 s at 375k (was 20.6 of 95.7 s); 42 and 48 iterations against 40 and 50
#: (the inexact face solves differ with the kept hierarchy; benchmarks/scale/README.md,
#: issue 18)
CHECK_SHARE = 0.10


def _check_interval(options: UzawaOptions, t_certificate: float, t_iteration: float) -> int:
    """Iterations between checks: as given, or such that checking costs about
    :data:`CHECK_SHARE` of the iterations' time (at most ``max_check_interval``)."""
    if options.check_every is not None:
        return options.check_every
    m = int(np.ceil(t_certificate / (CHECK_SHARE * max(t_iteration, 1e-9))))
    return int(min(max(m, 1), options.max_check_interval))


def _next_check(options: UzawaOptions, n: int, interval: int, history: list, tol: float) -> int:
    """The iteration of the next certificate check after the one at ``n``.

    A given ``check_every``: every ``check_every`` iterations. Automatic: after
    ``interval`` iterations (:func:`_check_interval`), sooner if the worst residual's
    linear decay between the last two checks says it reaches ``tol`` before that (Uzawa
    converges linearly and regularly: on the default 3D problem at 118k tetrahedra the
    ratio of consecutive residuals stays within 0.70-0.74 over the last 30 iterations),
    so that a longer interval costs no iterations past convergence. Only where to look is
    predicted: the stopping test stays the certificate of the candidate at the check."""
    if options.check_every is not None:
        return n + options.check_every
    gap = interval
    if len(history) >= 2:
        (n1, w1), (n2, w2) = ((h["iteration"], h["kkt_worst"]) for h in history[-2:])
        if n2 > n1 and 0.0 < w2 < w1 and np.isfinite(w1) and w2 > tol:
            rate = np.log(w2 / w1) / (n2 - n1)  # < 0
            gap = min(gap, int(np.ceil(np.log(tol / w2) / rate)))
    return n + max(gap, 1)


def solve_uzawa(disc: Discretization, options: UzawaOptions = UzawaOptions()) -> Solution:
    """Uzawa's method (docs/methods.md) with the certificate as stopping test.

    Iteration n evaluates step (i) at ``u^n``; the certificate is evaluated at
    the candidate ``(R(eps(u^n)), u^n, U^n)`` (whose constitutive residual is
    zero by construction) and, unless :class:`~elastoplast.solvers.loop.Monitor`
    says stop, step (ii) gives ``u^{n+1}``. The answer is the last candidate,
    with its true residuals, whatever the status.

    ``options``: :class:`UzawaOptions`, a mapping of them or ``None``; its
    ``initial`` must be a solution of this discretisation (it reads ``u`` and the
    contact forces). Anything else is refused naming it, before any work.
    """
    options = check_inputs(disc, options, UzawaOptions)
    if options.initial is not None:
        check_solution(disc, options.initial, "initial", reads=("u", "contact_force"), start=True,
                       advice=WARM_START_ADVICE)
    # a non-finite iterate is the monitor's DIVERGED, not a floating-point warning
    with iterative_context(disc, options.factorization), np.errstate(all="ignore"):
        return _solve_uzawa(disc, options)


def _solve_uzawa(disc: Discretization, options: UzawaOptions) -> Solution:
    rho = check_rho(default_rho(disc.material) if options.rho is None else options.rho, disc.material)
    t_start = time.perf_counter()
    timings = {"setup": 0.0, "stresses": 0.0, "contact": 0.0, "certificate": 0.0}

    nd, units = nondimensionalize(disc)
    monitor = Monitor("uzawa", disc, nd, units, options, divergence_factor=options.divergence_factor, t_start=t_start)
    rho_nd = rho * units.E  # the step in the scaled units, where E = 1
    weight = None if options.rigid_weight is None else options.rigid_weight / units.length ** (disc.dim - 2)
    proj = metric_projection(nd, units.length, np.eye(nd.k), options.factorization, weight, options.inner_rtol,
                             options.contact_qp)
    u, U, lam = _initial_point(disc, nd, units, options, rho_nd)
    # the start must lie in K_h: project it (a step with rho = 0 is the pure projection)
    u, U, _ = proj(u, U, np.zeros(nd.n_free), 0.0, nd.force, nd.N, nd.psi)
    timings["setup"] = time.perf_counter() - t_start

    interval, n, checks, next_check, its_last, n_last = options.check_every or 1, 0, 0, 0, 0.0, 0
    while True:
        t0 = time.perf_counter()
        sigma, xi = project_stresses(nd.material, nd.strain(u), nd.state)  # step (i)
        r = nd.internal_force(sigma)
        t1 = time.perf_counter()
        timings["stresses"] += t1 - t0
        checked = n >= next_check or n >= options.max_iter
        if checked:
            verdict = monitor.check(n, sigma, xi, u, U, internal_force=r)
            timings["certificate"] += time.perf_counter() - t1
            checks += 1
            if verdict is not None:
                break
        t2 = time.perf_counter()
        u, U, lam = proj(u, U, r, rho_nd, nd.force, nd.N, nd.psi, lam)  # step (ii)
        timings["contact"] += time.perf_counter() - t2
        if checked:
            # the mean time of the iterations since the last check: the first projections, whose
            # contact set moves (a new face system per active-set iteration), cost several times a
            # later one, and a mean over every iteration carried them on to the end (at 1.03M
            # tetrahedra a check at nearly every iteration, 74 of a 307 s run)
            its = timings["stresses"] + timings["contact"]
            t_it = (its - its_last) / max(n - n_last, 1)
            its_last, n_last = its, n
            interval = _check_interval(options, timings["certificate"] / checks, t_it)
            next_check = _next_check(options, n, interval, monitor.history, options.tol)
        n += 1
    return monitor.solution(verdict, sigma, xi, u, U, iterations=n, timings=timings,
                            note=f"rho = {rho:.6g}, bound {rho_bound(disc.material):.6g}{projection_note(proj)}")


def load_sweep(disc: Discretization, forces: Sequence[float], options: UzawaOptions = UzawaOptions()) -> list[Solution]:
    """Solve for each force in turn, each solve warm-started from the previous one.

    Hencky's law is path independent, so the order changes the speed, not the
    answers. ``options.initial`` (if any) warm-starts the first solve.
    ``forces``: a sequence (list, tuple, 1-D array) of finite numbers > 0, each
    checked like ``load.force`` (errors name ``forces[i]``), all before the first solve.
    """
    from dataclasses import replace

    options = check_inputs(disc, options, UzawaOptions)
    if isinstance(forces, np.ndarray) and forces.ndim == 1:
        forces = forces.tolist()
    if isinstance(forces, (str, bytes)) or not isinstance(forces, Sequence):
        what = f"an array of shape {forces.shape}" if isinstance(forces, np.ndarray) else short_repr(forces)
        raise InputError("forces", f"expected a sequence of forces, e.g. [0.5 * F, F], got {what}")
    loads = []
    for i, F in enumerate(forces):
        try:
            loads.append(disc.with_force(F))
        except InputError as exc:
            raise InputError(f"forces[{i}]", exc.message) from None
    out: list[Solution] = []
    previous = options.initial
    for load in loads:
        sol = solve_uzawa(load, replace(options, initial=previous))
        out.append(sol)
        previous = sol
    return out
