"""The discrete problem (2.1) as conic programs, solved by Clarabel (docs/math.md).

* Stress form (S): minimise ``1/2 [tau_hat, tau_hat] + psi . lam`` over element
  stresses, hardening stresses and contact forces, subject to equilibrium, the
  force balance, one second-order cone per element and ``lam >= 0``.
  :func:`solve_conic` assembles Clarabel's data directly (fast);
  :func:`stress_program` is the same model in CVXPY (readable reference).
* Displacement form (D), its conic dual: :func:`displacement_program`.

All of them solve the problem in the O(1) units of
:func:`~elastoplast.fem.discretize.nondimensionalize` and return a certified
:class:`~elastoplast.certificate.solution.Solution` in the user's units.
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.fem.discretize import Discretization, Units, nondimensionalize
from elastoplast.fem.material import SQRT_3_2, return_mapping, von_mises
from elastoplast.fem.stress_form import (
    contact_sign_rows,
    deviatoric_basis,
    element_weights,
    equilibrium_rows,
    force_row,
    yield_rows,
)
from elastoplast.options import SolverOptions, option
from elastoplast.solvers.backends import ConicAnswer, clarabel_rows, clarabel_settings, solve_clarabel
from elastoplast.solvers.loop import check_inputs, within_tolerance
from elastoplast.solvers.polish import newton_polish
from elastoplast.certificate.solution import within_small_strains


@dataclass(frozen=True)
class ConicOptions(SolverOptions):
    """Settings of the conic methods (``tol``, ``max_iter``, ``time_limit``,
    ``progress``: :class:`~elastoplast.options.SolverOptions`).

    ``tol`` is what every method's ``tol`` is: the answer is CONVERGED when
    the certified worst KKT residual is at most ``tol``. ``ip_tol`` is
    Clarabel's own relative gap and feasibility tolerance, and ``max_iter``
    and ``time_limit`` bound the interior point. Raw dual displacements are
    only as accurate as the gap allows; with ``polish`` (default) the interior
    point only has to find the plastic and contact sets, and Newton steps do
    the rest: on nine test problems ip_tol = 1e-6, 1e-8 and 1e-10 all
    certified at 1e-14..1e-16, 1e-8 saving 10-30% of the time of 1e-10
    (21.1 s -> 16.7 s on a 12.7k-tetrahedra gmsh mesh)."""

    max_iter: int = option(200, int, "interior-point iteration limit", lo=1, hi=10_000)
    ip_tol: float = option(1e-8, float, "Clarabel's gap and feasibility tolerance", lo=1e-14, hi=1e-3)
    verbose: bool = option(False, bool, "Clarabel's own iteration log (on stdout)", persist=False)
    #: Clarabel's KKT factorisation: "qdldl", "faer" or "auto" (see :func:`kkt_solver`)
    linear_solver: str = option("auto", str, "Clarabel's KKT factorisation", choices=("auto", "qdldl", "faer"))
    #: finish with active-set Newton steps (elastoplast.solvers.polish); the certificate
    #: decides which of the two candidates is returned
    polish: bool = option(True, bool, "finish with active-set Newton steps (elastoplast.solvers.polish)")


# ----------------------------------------------------------------------------
# conic pieces, each a few lines
# ----------------------------------------------------------------------------


def stress_form_data(disc: Discretization, with_yield: bool = True):
    """Clarabel data ``(P, q, A, b, cones, layout)`` of (S) on ``disc``.

    The unknowns are energy-normalised, ``tau_hat_T = sqrt|T| tau_T`` and
    ``xi_hat_T = sqrt|T| xi_T``, so the quadratic term is the same small block
    ``A`` (and ``1/H``) for every element. Graded meshes have element volumes
    spanning many decades; with ``|T| A`` blocks the solver's static
    regularisation swamped the smallest elements (measured: constitutive
    residual 5e-3 on a 2D mesh with volumes down to 1e-10 of the body's).
    """
    n, k, nc = disc.n_elements, disc.k, disc.n_contact
    m = disc.material
    has_xi = with_yield and m.hardening > 0
    tau_col, xi_col = 0, n * k
    lam_col = xi_col + (n if has_xi else 0)
    n_cols = lam_col + nc

    Acomp = np.triu(m.compliance(disc.dim))
    blocks = [sp.kron(sp.eye(n), sp.csr_matrix(Acomp))]
    if has_xi:
        blocks.append(sp.eye(n) / m.hardening)
    blocks.append(sp.csr_matrix((nc, nc)))
    P = sp.block_diag(blocks, format="csc")
    q = np.zeros(n_cols)
    q[lam_col:] = disc.psi
    if disc.state is not None:  # (S_n): the quadratic centred at the state, 1/2 [t - s_n, t - s_n]
        w = element_weights(disc)
        q[:n * k] = -(w[:, None] * disc.state.strain).ravel()
        if has_xi:
            q[xi_col:lam_col] = -w * disc.state.xi / m.hardening

    groups = [equilibrium_rows(disc, tau_col, lam_col), force_row(disc, lam_col), contact_sign_rows(nc, lam_col)]
    if with_yield:
        groups.append(yield_rows(k, element_weights(disc), m.yield_stress, tau_col, xi_col if has_xi else None))
    blocks, rhs, cones = clarabel_rows(groups, n_cols)
    A = sp.vstack(blocks[:2], format="csc")
    if with_yield:
        A = sp.vstack([A, blocks[2]], format="csc")
    b = np.concatenate(rhs)
    layout = dict(tau=slice(0, n * k), xi=slice(xi_col, lam_col) if has_xi else None, lam=slice(lam_col, n_cols),
                  eq=slice(0, disc.n_free), force=disc.n_free)
    return P, q, A, b, cones, layout


#: 3D meshes from this many elements use faer (supernodal, multithreaded), smaller ones QDLDL.
#: Measured on the 3D sphere, whole conic solve, 2 cores: 12,288 tetrahedra QDLDL 6.0 s /
#: faer 10.2 s; 24,000: 31.8 s / 21.7 s; 41,472: 123.5 s / 45.6 s. In 2D QDLDL was as
#: fast or faster up to 25,600 triangles (4.6 s / 8.4 s).
CONIC_FAER_FROM_ELEMENTS_3D = 16_000


def kkt_solver(disc: Discretization, options: ConicOptions) -> str:
    """The Clarabel ``direct_solve_method`` for this problem."""
    if options.linear_solver != "auto":
        return options.linear_solver
    return "faer" if disc.dim == 3 and disc.n_elements >= CONIC_FAER_FROM_ELEMENTS_3D else "qdldl"


def _status(answer: ConicAnswer) -> tuple[Status, str]:
    status, msg = answer.status, answer.label
    if status is Status.INFEASIBLE:
        msg += " (no equilibrium stress field inside the yield surface carries F: the force exceeds the limit load)"
    return status, msg


def _back(units: Units, sigma, xi, u_free, U, lam):
    return (sigma * units.stress, xi * units.stress, u_free * units.displacement,
            U * units.displacement, None if lam is None else lam * units.force)


def _fail(disc: Discretization, method: str, status: Status, message: str, iterations: int, timings) -> Solution:
    """A certified 'solution' of zeros, for solvers that produced nothing usable."""
    z = np.zeros
    return make_solution(disc, method=method, status=status, sigma=z((disc.n_elements, disc.k)),
                         xi=z(disc.n_elements), u_free=z(disc.n_free), U=0.0, contact_force=z(disc.n_contact),
                         iterations=iterations, timings=timings, message=message)


#: above this many mean contact pressures the yield stress is first tried as inactive
ELASTIC_FIRST = 10.0


def elastic_first(solve_scaled):
    """Run ``solve_scaled(nd, with_yield) -> (status, msg, iters, sigma, xi, u, U, lam)``,
    first without yield cones when the yield stress is large.

    On a step from a state the yield stress of each element is ``sigma_y + xi_n``
    and an elastic answer keeps ``xi = xi_n``.

    A yield stress far above the stresses (an elastic limit) puts the cones'
    constants orders of magnitude above the iterates, which stalls interior
    points. The elastic contact solution satisfies every KKT condition of (2.1)
    when its von Mises stress stays within sigma_y everywhere (xi = 0, no plastic
    flow), so it is then the answer; otherwise the cones are put back.
    """

    def run(nd: Discretization):
        if nd.material.yield_stress >= ELASTIC_FIRST:  # nd is in mean-pressure units
            out = solve_scaled(nd, False)
            limit = nd.material.yield_stress + (0.0 if nd.state is None else nd.state.xi)
            if out[0] is Status.CONVERGED and np.all(von_mises(out[3]) <= limit):
                if nd.state is not None:
                    out = out[:4] + (nd.state.xi.copy(),) + out[5:]
                return out
            iters = out[2]
            out = solve_scaled(nd, True)
            return out[:2] + (iters + out[2],) + out[3:]
        return solve_scaled(nd, True)

    return run


def solve_conic(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """Stress form (S) assembled directly for Clarabel.

    With Clarabel's KKT convention ``P x + q + A^T z = 0`` the displacements are
    ``u = -z_equilibrium`` and ``U = -z_force`` (checked by the certificate).
    ``options``: :class:`ConicOptions`, a mapping of them or ``None``.
    """
    options = check_inputs(disc, options, ConicOptions)
    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}

    @elastic_first
    def scaled(nd: Discretization, with_yield: bool):
        t0 = time.perf_counter()
        P, q, A, b, cones, lay = stress_form_data(nd, with_yield)
        t1 = time.perf_counter()
        res = solve_clarabel(P, q, A, b, cones, clarabel_settings(options, kkt_solver(nd, options)))
        timings["setup"] += t1 - t0
        timings["solve"] += time.perf_counter() - t1
        status, msg = _status(res)
        x, z = res.x, res.z
        n, w = nd.n_elements, element_weights(nd)
        sigma = x[lay["tau"]].reshape(n, nd.k) / w[:, None]
        xi = x[lay["xi"]] / w if lay["xi"] is not None else np.zeros(n)
        return status, msg, res.iterations, sigma, xi, -z[lay["eq"]], -z[lay["force"]], x[lay["lam"]]

    return _finish(disc, "conic", scaled, timings, options)


def _finish(disc: Discretization, method: str, scaled, timings: dict[str, float], options: ConicOptions) -> Solution:
    """Scale, solve, polish, scale back and certify; infeasible/failed runs say so."""
    t0 = time.perf_counter()
    nd, units = nondimensionalize(disc)
    if options.progress:
        print(f"{method}: interior point on {disc.n_elements} yield cones ...", file=sys.stderr, flush=True)
    status, msg, iters, sigma, xi, u_free, U, lam = scaled(nd)
    if options.progress:
        print(f"{method}: {msg} after {iters} iterations, {time.perf_counter() - t0:.1f} s"
              + ("; polishing" if options.polish else ""), file=sys.stderr, flush=True)
    if status is Status.INFEASIBLE or sigma is None or not np.all(np.isfinite(u_free)):
        timings["total"] = time.perf_counter() - t0
        return _fail(disc, method, status, msg, iters, timings)
    candidates = [(sigma, xi, u_free, U, lam, msg)]
    if options.polish:
        t1 = time.perf_counter()
        pol = newton_polish(nd, u_free, U, lam)
        sig_p, xi_p, _ = return_mapping(nd.material, nd.strain(pol.u_free), nd.state)
        timings["polish"] = time.perf_counter() - t1
        candidates.append((sig_p, xi_p, pol.u_free, pol.U, None,
                           f"{msg}; polished by {pol.steps} Newton step(s)" + ("" if pol.converged else " (not converged)")))
    timings["total"] = time.perf_counter() - t0
    best = None
    for sigma, xi, u_free, U, lam, message in candidates:
        sigma, xi, u_free, U, lam = _back(units, sigma, xi, u_free, U, lam)
        sol = make_solution(disc, method=method, status=status, sigma=sigma, xi=xi, u_free=u_free, U=U,
                            contact_force=lam, iterations=iters, timings=timings, message=message)
        if best is None or _rank(sol) < _rank(best):
            best = sol
    # the certificate, not the interior point's own verdict, decides
    if within_tolerance(best.kkt, options.tol):
        return within_small_strains(disc, replace(best, status=Status.CONVERGED))
    verdict = status if status is not Status.CONVERGED else Status.FAILED
    return replace(best, status=verdict,
                   message=f"{best.message}; certified KKT residual {best.kkt.worst:.1e} above tol {options.tol:g}")


def _rank(sol: Solution) -> float:
    """The worst residual, NaN counted as worst of all."""
    worst = sol.kkt.worst
    return worst if np.isfinite(worst) else np.inf


# ----------------------------------------------------------------------------
# CVXPY models: the readable reference
# ----------------------------------------------------------------------------


def _factor(M: np.ndarray) -> np.ndarray:
    """``L`` with ``M = L L^T`` (so ``t M t = |t L|^2`` for row vectors)."""
    return np.linalg.cholesky(M)


def stress_program(disc: Discretization, with_yield: bool = True):
    """(S) in CVXPY: returns ``(problem, variables, constraints)``.

    The variables are the energy-normalised ``tau_hat = sqrt|T| tau`` and
    ``xi_hat = sqrt|T| xi`` (see :func:`stress_form_data` for why).
    """
    import cvxpy as cp

    n, k, nc = disc.n_elements, disc.k, disc.n_contact
    m = disc.material
    w = element_weights(disc)
    tau = cp.Variable((n, k), name="tau_hat")
    lam = cp.Variable(nc, name="lam")
    xi = cp.Variable(n, name="xi_hat") if with_yield and m.hardening > 0 else None
    # (S_n) on a step from a state: the same model, the quadratic centred at the state
    tau0 = 0.0 if disc.state is None else w[:, None] * disc.state.sigma
    xi0 = 0.0 if disc.state is None else w * disc.state.xi
    energy = 0.5 * cp.sum_squares((tau - tau0) @ _factor(m.compliance(disc.dim)))
    if xi is not None:
        energy += 0.5 * cp.sum_squares(xi - xi0) / m.hardening
    weighted = cp.reshape(cp.multiply(w[:, None], tau), (n * k,), order="C")
    cons = {
        "equilibrium": disc.B.T @ weighted - disc.N.T @ lam == 0,
        "force": cp.sum(lam) == disc.force,
        "sign": lam >= 0,
    }
    if with_yield:
        cons["yield"] = cp.SOC(w * m.yield_stress + (xi if xi is not None else 0.0),
                               SQRT_3_2 * (tau @ deviatoric_basis(k)).T, axis=0)
    prob = cp.Problem(cp.Minimize(energy + disc.psi @ lam), list(cons.values()))
    return prob, {"tau": tau, "xi": xi, "lam": lam}, cons


def displacement_program(disc: Discretization):
    """(D) in CVXPY. The plastic unknowns are trace-free by construction and
    energy-normalised: ``sqrt|T| p_T = Q p_hat_T``, ``kappa_hat_T = sqrt|T| kappa_T``."""
    import cvxpy as cp

    n, k = disc.n_elements, disc.k
    m = disc.material
    w = element_weights(disc)
    v = cp.Variable(disc.n_free, name="v")
    V = cp.Variable(name="V")
    p_hat = cp.Variable((n, k - 1), name="p_hat")
    kappa = cp.Variable(n, name="kappa_hat")
    eps = cp.reshape(disc.B @ v, (n, k), order="C")
    # (D_n) on a step from a state: W_n(e) is W at e + A sigma_n with sigma_y + xi_n, up to a constant
    eps0 = 0.0 if disc.state is None else w[:, None] * disc.state.strain
    limit = m.yield_stress if disc.state is None else m.yield_stress + disc.state.xi
    elastic = cp.multiply(w[:, None], eps) + eps0 - p_hat @ deviatoric_basis(k).T
    energy = 0.5 * cp.sum_squares(elastic @ _factor(m.stiffness(disc.dim)))
    dissipation = (w * limit) @ kappa
    if m.hardening > 0:
        dissipation += 0.5 * m.hardening * cp.sum_squares(kappa)
    cons = {
        "flow": cp.SOC(kappa, np.sqrt(2.0 / 3.0) * p_hat.T, axis=0),
        "contact": disc.N @ v + disc.psi - V >= 0,
    }
    prob = cp.Problem(cp.Minimize(energy + dissipation - disc.force * V), list(cons.values()))
    return prob, {"v": v, "V": V, "p": p_hat, "kappa": kappa, "eps": eps}, cons


#: what CVXPY's advice "solve with verbose=True" is on the command line and from Python
VERBOSE_ADVICE = "--option verbose=true (verbose=True from Python) shows Clarabel's log"


def _cvxpy_solve(prob, options: ConicOptions, solver: str = "qdldl"):
    """``(status, message)`` of CVXPY's Clarabel solve. CVXPY reports Clarabel's
    ``MaxTime`` and ``MaxIterations`` alike as ``user_limit``: a run that used up a
    time limit it was given ended at that limit, any other at ``max_iter``."""
    import cvxpy as cp

    kw = dict(tol_gap_abs=options.ip_tol, tol_gap_rel=options.ip_tol, tol_feas=options.ip_tol,
              tol_ktratio=min(1e-6, options.ip_tol), max_iter=options.max_iter,
              time_limit=float("inf") if options.time_limit is None else options.time_limit,
              direct_solve_method=solver)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():  # the status says it; no warning on top
            warnings.simplefilter("ignore", UserWarning)
            prob.solve(solver=cp.CLARABEL, verbose=options.verbose, **kw)
    except cp.error.SolverError as exc:
        text = str(exc).replace(", or solve with verbose=True for more information", "")
        return Status.FAILED, f"CVXPY/Clarabel: {text} ({VERBOSE_ADVICE})"
    raw = prob.status
    if raw in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return Status.CONVERGED, f"CVXPY: {raw}"
    if raw in (cp.INFEASIBLE, cp.UNBOUNDED, cp.INFEASIBLE_INACCURATE, cp.UNBOUNDED_INACCURATE):
        return Status.INFEASIBLE, f"CVXPY: {raw} (the force exceeds the limit load)"
    if raw == cp.USER_LIMIT:
        stats = prob.solver_stats
        used = stats.solve_time if stats is not None and stats.solve_time is not None else time.perf_counter() - t0
        if options.time_limit is not None and used >= options.time_limit:
            return Status.TIME_LIMIT, f"CVXPY: {raw} (time limit of {options.time_limit:g} s reached)"
        return Status.MAX_ITERATIONS, f"CVXPY: {raw} (max_iter = {options.max_iter} interior-point iterations reached)"
    return Status.FAILED, f"CVXPY: {raw} ({VERBOSE_ADVICE})"


def _solver_stats(prob) -> int:
    stats = prob.solver_stats
    return int(stats.num_iters) if stats is not None and stats.num_iters is not None else 0


def _cvxpy_scaled(build, extract, options: ConicOptions, timings: dict[str, float]):
    """``scaled(nd, *args)`` for :func:`_finish`: build the CVXPY model with
    ``build(nd, *args)``, solve it, and read the answer with
    ``extract(nd, variables, constraints) -> (sigma, xi, u, U, lam)``."""

    def scaled(nd: Discretization, *args):
        t0 = time.perf_counter()
        prob, var, cons = build(nd, *args)
        t1 = time.perf_counter()
        status, msg = _cvxpy_solve(prob, options, kkt_solver(nd, options))
        timings["setup"] += t1 - t0
        timings["solve"] += time.perf_counter() - t1
        if status is not Status.CONVERGED:
            return (status, msg, _solver_stats(prob)) + (None,) * 5
        return (status, msg, _solver_stats(prob)) + extract(nd, var, cons)

    return scaled


def _stress_answer(nd: Discretization, var, cons):
    w = element_weights(nd)
    xi = var["xi"].value / w if var["xi"] is not None else np.zeros(nd.n_elements)
    return (var["tau"].value / w[:, None], xi, -cons["equilibrium"].dual_value, -float(cons["force"].dual_value),
            var["lam"].value)


def _displacement_answer(nd: Discretization, var, cons):
    m, k, w = nd.material, nd.k, element_weights(nd)
    p = var["p"].value @ deviatoric_basis(k).T / w[:, None]
    xi = m.hardening * var["kappa"].value / w
    eps = var["eps"].value
    if nd.state is not None:  # the increments of a step: add the state
        eps, xi = eps + nd.state.strain, xi + nd.state.xi
    sigma = (eps - p) @ m.stiffness(nd.dim)
    return sigma, xi, var["v"].value, float(var["V"].value), cons["contact"].dual_value


def solve_conic_cvxpy(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """(S) through CVXPY. CVXPY's equality duals enter its Lagrangian with a plus
    sign, so ``u = -y_equilibrium`` and ``U = -y_force`` as for raw Clarabel.
    ``options``: :class:`ConicOptions`, a mapping of them or ``None``."""
    options = check_inputs(disc, options, ConicOptions)
    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}
    scaled = elastic_first(_cvxpy_scaled(stress_program, _stress_answer, options, timings))
    return _finish(disc, "conic-cvxpy", scaled, timings, options)


def solve_conic_displacement(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """(D) through CVXPY: ``sigma = C (eps - p)``, ``xi = H kappa``, contact forces
    are the multipliers of the contact inequalities.
    ``options``: :class:`ConicOptions`, a mapping of them or ``None``."""
    options = check_inputs(disc, options, ConicOptions)
    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}
    scaled = _cvxpy_scaled(displacement_program, _displacement_answer, options, timings)
    return _finish(disc, "conic-displacement", scaled, timings, options)
