"""Semismooth Newton / primal-dual active set on the displacement form (D).

For fixed strains the minimum of (D) over the plastic strains is reached by the
return mapping, so (D) is the convex, once differentiable problem

    minimise  f(u, U) = sum_T |T| W(B_T u) - F U   subject to  N u + psi - U >= 0,

with ``grad W = R`` (the stresses of the return mapping) and a semismooth
gradient. In the variables ``y = (u with the vertical contact dofs replaced by
w_i = u_{i,d} - U, U)`` the contact inequalities become bounds
``w_i >= -psi_i`` (the gap is ``g_i = w_i + psi_i``), and the method is
Bertsekas' projected Newton method for bound constraints:

* the active set: contact variables at (or within ``eps_k`` of) their bound
  whose gradient ``lam_i = r_{i,d}`` pushes into the obstacle;
* the Newton step on the face they define, with the consistent tangent of the
  return mapping (:func:`~elastoplast.fem.material.consistent_tangent`:
  ``C_ep = C - 6 mu^2/(3 mu + H) n n^T - 6 mu^2 dkappa/q (Dev - n n^T)`` on
  plastic elements, from differentiating the radial return); the active variables go to their
  bound, the Hessian row of ``U`` couples the rigid body to every contact node;
* an Armijo line search on f along the projection arc ``P[y + alpha d]``, which
  keeps every iterate feasible and makes the method converge from ``u = 0``.

The Hessian keeps one sparsity pattern for every active set (active rows and
columns are replaced by their diagonal), so the sparse factorisation's
symbolic analysis is done once; with PARDISO a stale factorisation also serves
as a preconditioner for conjugate gradients while that is cheaper than
refactorising (:class:`NewtonOptions`). On large meshes the face systems are
solved inexactly instead, by conjugate gradients with smoothed-aggregation AMG
(:class:`AMGHessian`, :mod:`elastoplast.linalg.amg`), to the relative residual of
Eisenstat and Walker's forcing term (:func:`forcing_term`); every CG iterate
is a descent direction on the face, so the line search and the projection
arc are unchanged. Every iterate is judged by the KKT certificate of
docs/certificate.md, whatever the linear solver.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, replace

import numpy as np

from elastoplast.certificate.kkt import work_density
from elastoplast.certificate.solution import Solution, Status, check_solution
from elastoplast.fem.discretize import Discretization, nondimensionalize
from elastoplast.fem.material import return_mapping
from elastoplast.linalg.amg import contact_dofs, one_blas_thread
from elastoplast.linalg.direct import pardiso_available
from elastoplast.options import LOOSEST_TOL, TIGHTEST_TOL, SolverOptions, option
from elastoplast.solvers.hessian import AMGHessian, DirectHessian, State
from elastoplast.solvers.loop import Monitor, Verdict, check_inputs


@dataclass(frozen=True)
class NewtonOptions(SolverOptions):
    """Settings of :func:`solve_newton` (``tol``, ``max_iter``, ``time_limit``,
    ``progress``: :class:`~elastoplast.options.SolverOptions`).

    ``linear_solver``: ``"pardiso"`` (MKL, via pypardiso), ``"splu"`` (SciPy),
    ``"amg"`` (conjugate gradients with smoothed-aggregation AMG,
    :class:`AMGHessian`) or ``"auto"``: AMG from :data:`NEWTON_AMG_FROM_ELEMENTS`
    elements on, PARDISO below when installed, else SuperLU. Measured on the 3D
    sphere with 111k tetrahedra (52k dofs): PARDISO 0.5 s analysis + 2.1 s
    factorisation, SciPy's SuperLU 41 s (COLAMD), cholespy 53 s (see
    benchmarks/methods/README.md); the direct and iterative paths against each
    other from 12k to 1M tetrahedra in benchmarks/scale.
    ``forcing_max`` (AMG only): the loosest relative residual asked of a Newton
    step's linear solve (:func:`forcing_term` tightens it as Newton converges).
    ``amg_reuse`` (AMG only): keep a multigrid hierarchy across steps while a new
    one would not pay for itself (:class:`~elastoplast.linalg.amg.FaceSystems`).
    ``reuse_factorization``: first try conjugate gradients preconditioned by the
    last factorisation (within 0.3 of a factorisation's measured cost). Off by
    default: on the 3D sphere (41k tetrahedra) it saved one factorisation of
    eight and no time, and with a looser CG tolerance (1e-2) the inexact steps
    made the contact set oscillate (28 Newton steps instead of 8).
    ``load_steps``: solve for ``F/n, 2F/n, ..., F`` in turn, each from the last.
    ``threads``: MKL threads for PARDISO (None: MKL's default). On a machine
    shared with other jobs one thread avoids OpenMP's busy waiting.
    """

    tol: float = option(1e-10, float, "bound on every relative KKT residual of the answer",
                        lo=TIGHTEST_TOL, hi=LOOSEST_TOL)
    max_iter: int = option(100, int, "Newton step limit", lo=1, hi=10_000)
    linear_solver: str = option("auto", str, "linear solver of the Newton systems",
                                choices=("auto", "pardiso", "splu", "amg"))
    reuse_factorization: bool = option(False, bool, "try CG preconditioned by the last factorisation first")
    load_steps: int = option(1, int, "solve for F/n, 2F/n, ..., F in turn", lo=1, hi=1000)
    threads: int | None = option(None, int, "MKL threads for PARDISO (none: MKL's default)", lo=1, hi=1024,
                                 none=True, persist=False)
    armijo: float = option(1e-4, float, "sufficient-decrease constant of the line search", lo=0.0, hi=0.5,
                           lo_open=True)
    forcing_max: float = option(1e-2, float, "amg: largest relative residual of a Newton step's linear solve",
                                lo=1e-12, hi=0.5)
    amg_reuse: bool = option(True, bool, "amg: keep a multigrid hierarchy while a new one would not pay for itself")


#: "auto" takes AMG-preconditioned CG from this many elements on, by the direct
#: solver it would otherwise use and the dimension. Measured (benchmarks/scale, the
#: 3D sphere, Newton to KKT 1e-8, CPU seconds): AMG against PARDISO 0.7 / 1.4 s at
#: 12k tetrahedra, 1.2 / 2.7 at 24k, 3.5 / 8.6 at 53k, 10.5 / 30 at 118k, 36 / 184
#: at 375k; AMG wins from the smallest size measured, so below 20k, where both take
#: about a second, the direct path (exact, the reference) is kept. SuperLU is slower
#: than PARDISO (41 s for one factorisation at 111k). 2D (cylinder_2d, benchmarks/scale
#: README.md): PARDISO 2.2 / AMG 5.1 s at 25.6k triangles, 7.1 / 42.9 s at 102k: direct
#: factorisations fill in little in 2D, so "auto" stays direct there at any size here.
NEWTON_AMG_FROM_ELEMENTS = {"pardiso": {2: 10_000_000, 3: 20_000}, "splu": {2: 10_000_000, 3: 20_000}}

#: how to warm-start from a solution of the mesh before a refinement (what adapt does)
PROLONG_ADVICE = ("interpolate its displacements onto this mesh with ep.prolong_p1: "
                  "dataclasses.replace(sol, u=ep.prolong_p1(state, sol.u)), state from ep.refine")


# ----------------------------------------------------------------------------
# the Hessian on a fixed sparsity pattern
# ----------------------------------------------------------------------------


# ----------------------------------------------------------------------------
# sparse SPD solves
# ----------------------------------------------------------------------------


# ----------------------------------------------------------------------------
# the method
# ----------------------------------------------------------------------------


def to_displacements(y: np.ndarray, cdofs: np.ndarray) -> tuple[np.ndarray, float]:
    """``(u, U)`` from y: ``u_c = w + U`` at the vertical contact dofs."""
    u = y[:-1].copy()
    u[cdofs] += y[-1]
    return u, float(y[-1])


def to_variables(u: np.ndarray, U: float, cdofs: np.ndarray) -> np.ndarray:
    y = np.append(u, U)
    y[cdofs] -= U
    return y


def evaluate(disc: Discretization, cdofs: np.ndarray, y: np.ndarray, tangent: bool = True,
             gradient: bool = True) -> State:
    """Stresses, gradient ``T^T (r, -F)``, energy f and (if ``tangent``) the
    consistent tangents of the plastic elements at y.

    The gradient is ``r = sum_T |T| B_T^T sigma_T`` on the u part (the contact
    rows give ``lam_i = r_{i,d}``) and ``sum_i lam_i - F`` for U. ``gradient=False``
    leaves it out (``grad`` None; :func:`with_gradient` adds it): a trial point of the
    line search needs the energy alone.
    """
    u, U = to_displacements(y, cdofs)
    eps = disc.strain(u)
    sigma, xi, dkappa = return_mapping(disc.material, eps, disc.state)
    plastic = np.flatnonzero(dkappa > 0.0)
    st = State(y, u, U, sigma, xi, plastic, None, None, energy(disc, sigma, dkappa, U), eps[plastic])
    if gradient:
        st = with_gradient(disc, cdofs, st)
    return st.with_tangent(disc) if tangent else st


def with_gradient(disc: Discretization, cdofs: np.ndarray, st: State) -> State:
    """``st`` with its gradient (:func:`evaluate`), from its stresses."""
    if st.grad is not None:
        return st
    r = disc.internal_force(st.sigma)
    return replace(st, grad=np.append(r, r[cdofs].sum() - disc.force))


def energy(disc: Discretization, sigma: np.ndarray, kappa: np.ndarray, U: float) -> float:
    """f = (D)'s objective, :func:`~elastoplast.certificate.solution.value_displacement_form`,
    from the return mapping already done at the point (one mapping per line-search
    trial, not two): ``sum_T |T| W - F U`` with the density of
    :func:`~elastoplast.certificate.kkt.work_density` (a step's on a loading path)."""
    return float(disc.volumes @ work_density(disc, sigma, kappa)) - disc.force * U


def project(y: np.ndarray, cdofs: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """Projection onto the bounds ``w_i >= -psi_i``: the feasible set K_h in y."""
    out = y.copy()
    out[cdofs] = np.maximum(out[cdofs], lower)
    return out


def active_set(st: State, cdofs: np.ndarray, lower: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """Bertsekas' eps-active set: contact variables within ``eps_k`` of their
    bound whose gradient (the contact force) is nonnegative, with
    ``eps_k = min(1e-3, |y - P[y - D grad]|_inf)``, ``D`` the inverse Hessian diagonal.

    If it is empty the contact variable nearest its bound is taken, so that the
    face Hessian is nonsingular (U alone is not bounded below)."""
    y, g = st.y, st.grad
    step = y - project(y - g / diag, cdofs, lower)
    eps_k = min(1e-3, float(np.abs(step).max()))
    dist = y[cdofs] - lower
    act = (dist <= eps_k) & (g[cdofs] >= 0.0)
    if not np.any(act):
        act[np.argmin(dist)] = True
    return act


def forcing_term(kkt: float, kkt_prev: float | None, eta_prev: float | None, eta_max: float, tol: float) -> float:
    """Relative residual asked of the linear solve (inexact Newton).

    Eisenstat & Walker's choice 2 (1996), ``eta = 0.9 (kkt / kkt_prev)^2``,
    with their safeguard ``eta >= 0.9 eta_prev^2`` when that exceeds 0.1,
    capped by ``eta_max``; ``kkt`` is the certificate's worst residual, so the
    solve tightens as the iteration converges superlinearly. It is never
    tighter than ``0.1 tol / kkt``: a step whose linear error is that small
    already lands below ``tol`` (no oversolving), nor than 1e-12.
    """
    if kkt_prev is None or eta_prev is None or not (kkt_prev > 0 and np.isfinite(kkt)):
        return eta_max
    eta = 0.9 * (kkt / kkt_prev) ** 2
    if 0.9 * eta_prev**2 > 0.1:
        eta = max(eta, 0.9 * eta_prev**2)
    return float(min(eta_max, max(eta, 0.1 * tol / kkt, 1e-12)))


def newton_direction(hess, st, cdofs, lower, rtol, kkt_worst, timings):
    """Newton step on the face of the eps-active set: the active contact
    variables go to their bound, the others solve ``H_FF d_F = -grad_F - H_FA d_A``
    (to relative residual ``rtol`` on the iterative path)."""
    t0 = time.perf_counter()
    hess.update(st)
    timings["assembly"] += time.perf_counter() - t0
    act = active_set(st, cdofs, lower, hess.diagonal())
    n = st.y.size
    fixed = np.zeros(n, dtype=bool)
    fixed[cdofs[act]] = True
    d_fixed = np.zeros(n)
    d_fixed[cdofs[act]] = lower[act] - st.y[cdofs[act]]
    rhs = -st.grad - hess.matvec(d_fixed)
    return hess.solve_face(fixed, rhs, d_fixed, rtol, kkt_worst, timings)


def line_search(disc, cdofs, lower, st, direction, armijo):
    """Armijo backtracking along the projection arc ``P[y + alpha d]``:
    accept when ``f(y_alpha) <= f(y) + armijo grad . (y_alpha - y)`` (up to
    rounding of f). Returns ``(state or None, alpha)``. A rejected trial costs its
    return mapping and energy only: the gradient (a product ``B^T sigma``) is formed
    at the accepted point alone (the first step at 1.03M tetrahedra backtracks ten times)."""
    alpha = 1.0
    for _ in range(40):
        trial = project(st.y + alpha * direction, cdofs, lower)
        cand = evaluate(disc, cdofs, trial, tangent=False, gradient=False)
        if cand.energy <= st.energy + armijo * (st.grad @ (trial - st.y)) + 1e-14 * abs(st.energy):
            return with_gradient(disc, cdofs, cand).with_tangent(disc), alpha
        alpha *= 0.5
    return None, alpha


def choose_backend(disc: Discretization, requested: str) -> str:
    """The linear solver for ``requested``: ``"auto"`` takes AMG from
    :data:`NEWTON_AMG_FROM_ELEMENTS` elements on (the measured crossover with the
    direct solver available), PARDISO below it when installed, else SuperLU."""
    if requested in ("amg", "pardiso", "splu"):
        return requested
    direct = "pardiso" if pardiso_available() else "splu"
    return "amg" if disc.n_elements >= NEWTON_AMG_FROM_ELEMENTS[direct][disc.dim] else direct


def _newton_loop(nd, monitor, hess, cdofs, lower, y, options, timings, backend):
    """Newton steps over the load steps until the monitor stops; returns ``(verdict, state, steps)``."""
    steps = options.load_steps
    iteration, info = 0, {}
    kkt_prev, eta = None, None
    try:
        for step in range(1, steps + 1):
            target = nd.with_force(nd.force * step / steps)
            tol = options.tol if step == steps else max(options.tol, 1e-4)
            st = evaluate(target, cdofs, y)
            while True:
                t0 = time.perf_counter()
                verdict = monitor.check(iteration, st.sigma, st.xi, st.u, st.U, tol=tol, nd=target, load_step=step,
                                        energy=st.energy, **info)
                timings["certificate"] += time.perf_counter() - t0
                if verdict is not None:
                    break
                iteration += 1
                kkt = monitor.last.worst
                eta = forcing_term(kkt, kkt_prev, eta, options.forcing_max, tol)
                kkt_prev = kkt
                try:
                    direction, info = newton_direction(hess, st, cdofs, lower, eta, kkt, timings)
                except np.linalg.LinAlgError as exc:
                    verdict = Verdict(Status.FAILED, f"Newton: {exc}")
                    break
                if backend == "amg":
                    info["forcing"] = eta
                t0 = time.perf_counter()
                accepted, alpha = line_search(target, cdofs, lower, st, direction, options.armijo)
                timings["line_search"] += time.perf_counter() - t0
                info["step"] = alpha
                if accepted is None:
                    verdict = Verdict(Status.FAILED, "Newton: line search failed (no decrease of the energy along "
                                                     "the direction)")
                    break
                st = accepted
            if verdict.status is not Status.CONVERGED:
                break
            y = st.y
    finally:
        hess.release()
    return verdict, st, iteration


def solve_newton(disc: Discretization, options: NewtonOptions = NewtonOptions(), warm_start: Solution | None = None) -> Solution:
    """Projected semismooth Newton on (D); see the module docstring.

    Works on the nondimensionalised problem; every iterate is judged by
    :class:`~elastoplast.solvers.loop.Monitor` (the certificate), intermediate load
    steps to ``max(tol, 1e-4)``. On the iterative path the linear solves are
    inexact, to the relative residual of :func:`forcing_term`; the stopping
    test is the certificate all the same.

    ``options``: :class:`NewtonOptions`, a mapping of them or ``None``.
    ``warm_start``: a :class:`~elastoplast.certificate.solution.Solution` whose
    displacements ``u`` fit this mesh (only ``u`` and ``U`` are read; one of a coarser
    mesh is interpolated with :func:`~elastoplast.mesh.refinement.prolong_p1`).
    Anything else is refused naming the argument, before any work.
    """
    options = check_inputs(disc, options, NewtonOptions)
    if warm_start is not None:
        check_solution(disc, warm_start, "warm_start", reads=("u",), start=True, advice=PROLONG_ADVICE)
    with np.errstate(all="ignore"):  # a non-finite iterate is the monitor's DIVERGED, not a warning
        return _solve_newton(disc, options, warm_start)


def _solve_newton(disc: Discretization, options: NewtonOptions, warm_start: Solution | None) -> Solution:
    t_start = time.perf_counter()
    timings = {"setup": 0.0, "assembly": 0.0, "factorization": 0.0, "solve": 0.0, "line_search": 0.0, "certificate": 0.0}
    nd, units = nondimensionalize(disc)
    monitor = Monitor("newton", disc, nd, units, options, t_start=t_start)
    cdofs = contact_dofs(nd)
    backend = choose_backend(nd, options.linear_solver)
    lower = -nd.psi
    if warm_start is not None:
        y = to_variables(disc.free_displacement(warm_start.u) / units.displacement, warm_start.U / units.displacement, cdofs)
        y = project(y, cdofs, lower)
    else:  # u = 0, U = 0, projected: feasible also where the obstacle starts above the plane (psi < 0)
        y = project(np.zeros(nd.n_free + 1), cdofs, lower)
    with one_blas_thread() if backend == "amg" else contextlib.nullcontext():
        hess = AMGHessian(nd, units, options, cdofs) if backend == "amg" else DirectHessian(nd, options, backend)
        timings["setup"] = time.perf_counter() - t_start
        verdict, st, iteration = _newton_loop(nd, monitor, hess, cdofs, lower, y, options, timings, backend)
    note = f"projected semismooth Newton, {hess.backend}"
    if backend == "amg":
        note += f", {hess.setups} AMG set-up(s)"
    return monitor.solution(verdict, st.sigma, st.xi, st.u, st.U, iterations=iteration, timings=timings, note=note)
