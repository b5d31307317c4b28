"""The discrete problem (2.1) as conic programs, solved by Clarabel (MATH.md section 5).

* Stress form (S): minimise ``1/2 [tau_hat, tau_hat] + psi . lam`` over element
  stresses, hardening stresses and contact forces, subject to equilibrium, the
  force balance, one second-order cone per element and ``lam >= 0``.
  :func:`solve_conic` assembles Clarabel's data directly (fast);
  :func:`stress_program` is the same model in CVXPY (readable reference).
* Displacement form (D), its conic dual: :func:`displacement_program`.

All of them solve the problem in the O(1) units of
:func:`~elastoplast.discretize.nondimensionalize` and return a certified
:class:`~elastoplast.solution.Solution` in the user's units.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .discretize import Discretization, Units, nondimensionalize
from .material import SQRT_3_2, von_mises
from .solution import Solution, Status, make_solution


@dataclass(frozen=True)
class ConicOptions:
    """Interior-point settings. ``tol`` is Clarabel's relative gap and feasibility
    tolerance; reference runs want it tight (the displacements are dual
    variables and only as accurate as the gap)."""

    tol: float = 1e-12
    max_iter: int = 200
    verbose: bool = False
    time_limit: float = float("inf")
    #: Clarabel's KKT factorisation; QDLDL measured 2x faster than faer on the
    #: default 3D problem (5.5 s against 11.3 s, 12k tetrahedra)
    linear_solver: str = "qdldl"


def deviatoric_basis(k: int) -> np.ndarray:
    """Orthonormal basis ``Q (k, k-1)`` of trace-free Mandel vectors: ``|dev t| = |Q^T t|``."""
    Q = np.zeros((k, k - 1))
    Q[:3, 0] = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    Q[:3, 1] = np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)
    Q[3:, 2:] = np.eye(k - 3)
    return Q


# ----------------------------------------------------------------------------
# conic pieces, each a few lines
# ----------------------------------------------------------------------------


def yield_cone_rows(n_el: int, k: int, tau_col: int, xi_col: int | None, n_cols: int, sigma_y: float):
    """Rows of ``s = b - A x`` in the cone ``sqrt(3/2)|dev tau_T| <= sigma_y + xi_T``,
    one SOC of size k per element: ``s_T = (sigma_y + xi_T, sqrt(3/2) Q^T tau_T)``."""
    Q = deviatoric_basis(k)
    blocks = sp.kron(sp.eye(n_el), sp.csr_matrix(-SQRT_3_2 * Q.T))  # (n_el (k-1), n_el k)
    rows_dev = (np.arange(n_el)[:, None] * k + 1 + np.arange(k - 1)).ravel()
    coo = blocks.tocoo()
    r = [rows_dev[coo.row]]
    c = [tau_col + coo.col]
    v = [coo.data]
    if xi_col is not None:
        r.append(np.arange(n_el) * k)
        c.append(xi_col + np.arange(n_el))
        v.append(-np.ones(n_el))
    A = sp.csc_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))), shape=(n_el * k, n_cols))
    b = np.zeros(n_el * k)
    b[::k] = sigma_y
    return A, b


def contact_sign_rows(n_contact: int, lam_col: int, n_cols: int):
    """Rows ``s = -(-lam) = lam`` in the nonnegative cone: ``lam >= 0``."""
    A = sp.csc_matrix((-np.ones(n_contact), (np.arange(n_contact), lam_col + np.arange(n_contact))), shape=(n_contact, n_cols))
    return A, np.zeros(n_contact)


def equilibrium_rows(disc: Discretization, tau_col: int, lam_col: int, n_cols: int):
    """Zero-cone rows: ``sum_T |T| B_T^T tau_T - N^T lam = 0`` and ``sum lam = F``."""
    BtV = (disc.B.T @ sp.diags(np.repeat(disc.volumes, disc.k))).tocoo()
    Nt = disc.N.T.tocoo()
    n_free, n_c = disc.n_free, disc.n_contact
    rows = np.concatenate([BtV.row, Nt.row, np.full(n_c, n_free)])
    cols = np.concatenate([tau_col + BtV.col, lam_col + Nt.col, lam_col + np.arange(n_c)])
    vals = np.concatenate([BtV.data, -Nt.data, np.ones(n_c)])
    A = sp.csc_matrix((vals, (rows, cols)), shape=(n_free + 1, n_cols))
    b = np.zeros(n_free + 1)
    b[-1] = disc.force
    return A, b


def stress_form_data(disc: Discretization):
    """Clarabel data ``(P, q, A, b, cones, layout)`` of (S) on ``disc``."""
    import clarabel

    n, k, nc = disc.n_elements, disc.k, disc.n_contact
    m = disc.material
    has_xi = m.hardening > 0
    tau_col, xi_col = 0, n * k
    lam_col = xi_col + (n if has_xi else 0)
    n_cols = lam_col + nc

    Acomp = np.triu(m.compliance(disc.dim))
    blocks = [sp.kron(sp.diags(disc.volumes), sp.csr_matrix(Acomp))]
    if has_xi:
        blocks.append(sp.diags(disc.volumes / m.hardening))
    blocks.append(sp.csr_matrix((nc, nc)))
    P = sp.block_diag(blocks, format="csc")
    q = np.zeros(n_cols)
    q[lam_col:] = disc.psi

    A_eq, b_eq = equilibrium_rows(disc, tau_col, lam_col, n_cols)
    A_nn, b_nn = contact_sign_rows(nc, lam_col, n_cols)
    A_soc, b_soc = yield_cone_rows(n, k, tau_col, xi_col if has_xi else None, n_cols, m.yield_stress)
    A = sp.vstack([A_eq, A_nn, A_soc], format="csc")
    b = np.concatenate([b_eq, b_nn, b_soc])
    cones = [clarabel.ZeroConeT(b_eq.size), clarabel.NonnegativeConeT(nc)] + [clarabel.SecondOrderConeT(k)] * n
    layout = dict(tau=slice(0, n * k), xi=slice(xi_col, lam_col) if has_xi else None, lam=slice(lam_col, n_cols),
                  eq=slice(0, disc.n_free), force=disc.n_free)
    return P, q, A, b, cones, layout


def clarabel_settings(options: ConicOptions):
    import clarabel

    s = clarabel.DefaultSettings()
    s.verbose = options.verbose
    s.max_iter = options.max_iter
    s.time_limit = options.time_limit
    s.tol_gap_abs = options.tol
    s.tol_gap_rel = options.tol
    s.tol_feas = options.tol
    s.tol_ktratio = min(1e-6, options.tol)
    s.direct_solve_method = options.linear_solver
    return s


_CLARABEL_STATUS = {
    "Solved": Status.CONVERGED,
    "AlmostSolved": Status.CONVERGED,
    "PrimalInfeasible": Status.INFEASIBLE,
    "AlmostPrimalInfeasible": Status.INFEASIBLE,
    "DualInfeasible": Status.INFEASIBLE,
    "AlmostDualInfeasible": Status.INFEASIBLE,
    "MaxIterations": Status.MAX_ITERATIONS,
    "MaxTime": Status.MAX_ITERATIONS,
}


def _status(raw: str) -> tuple[Status, str]:
    status = _CLARABEL_STATUS.get(raw, Status.FAILED)
    msg = f"Clarabel: {raw}"
    if status is Status.INFEASIBLE:
        msg += " (no equilibrium stress field inside the yield surface carries F: the force exceeds the limit load)"
    return status, msg


def _back(units: Units, sigma, xi, u_free, U, lam):
    return (sigma * units.stress, xi * units.stress, u_free * units.displacement,
            U * units.displacement, lam * units.force)


def _fail(disc: Discretization, method: str, status: Status, message: str, iterations: int, timings) -> Solution:
    """A certified 'solution' of zeros, for solvers that produced nothing usable."""
    z = np.zeros
    return make_solution(disc, method=method, status=status, sigma=z((disc.n_elements, disc.k)),
                         xi=z(disc.n_elements), u_free=z(disc.n_free), U=0.0, contact_force=z(disc.n_contact),
                         iterations=iterations, timings=timings, message=message)


#: yield stress cap, in units of the mean contact pressure, for nearly elastic problems
YIELD_CAP = 1e3


def with_capped_yield(solve_scaled):
    """Run ``solve_scaled(nd) -> (status, msg, iters, sigma, xi, u, U, lam)`` on the
    scaled problem with the yield stress capped at ``YIELD_CAP`` mean pressures.

    A huge yield stress (an elastic limit) puts the cone's constant many orders
    above the stresses, which stalls interior-point methods. If no element
    reaches the cap the cone is inactive, and the capped solution is the
    solution: the certificate, which uses the true material, confirms it.
    Otherwise the cap grows a thousandfold, up to the true yield stress.
    """
    from dataclasses import replace

    def run(nd: Discretization):
        sigma_y = nd.material.yield_stress
        cap = min(sigma_y, YIELD_CAP)
        iters = 0
        while True:
            trial = replace(nd, problem=replace(nd.problem, material=replace(nd.material, yield_stress=cap)))
            out = solve_scaled(trial)
            iters += out[2]
            reached = out[0] is Status.CONVERGED and von_mises(out[3]).max() >= 0.999 * cap
            if cap >= sigma_y or not reached:
                return (out[0], out[1], iters) + tuple(out[3:])
            cap = min(sigma_y, cap * 1e3)

    return run


def solve_conic(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """Stress form (S) assembled directly for Clarabel.

    With Clarabel's KKT convention ``P x + q + A^T z = 0`` the displacements are
    ``u = -z_equilibrium`` and ``U = -z_force`` (checked by the certificate).
    """
    import clarabel

    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}

    @with_capped_yield
    def scaled(nd: Discretization):
        t0 = time.perf_counter()
        P, q, A, b, cones, lay = stress_form_data(nd)
        t1 = time.perf_counter()
        res = clarabel.DefaultSolver(P, q, A, b, cones, clarabel_settings(options)).solve()
        timings["setup"] += t1 - t0
        timings["solve"] += time.perf_counter() - t1
        status, msg = _status(str(res.status).split(".")[-1])
        x, z = np.asarray(res.x), np.asarray(res.z)
        n = nd.n_elements
        sigma = x[lay["tau"]].reshape(n, nd.k)
        xi = x[lay["xi"]] if lay["xi"] is not None else np.zeros(n)
        return status, msg, res.iterations, sigma, xi, -z[lay["eq"]], -z[lay["force"]], x[lay["lam"]]

    return _finish(disc, "conic", scaled, timings)


def _finish(disc: Discretization, method: str, scaled, timings: dict[str, float]) -> Solution:
    """Scale, solve, scale back and certify; infeasible/failed runs say so."""
    t0 = time.perf_counter()
    nd, units = nondimensionalize(disc)
    status, msg, iters, sigma, xi, u_free, U, lam = scaled(nd)
    timings["total"] = time.perf_counter() - t0
    if status in (Status.INFEASIBLE, Status.FAILED) or sigma is None:
        return _fail(disc, method, status, msg, iters, timings)
    sigma, xi, u_free, U, lam = _back(units, sigma, xi, u_free, U, lam)
    return make_solution(disc, method=method, status=status, sigma=sigma, xi=xi, u_free=u_free, U=U,
                         contact_force=lam, iterations=iters, timings=timings, message=msg)


# ----------------------------------------------------------------------------
# CVXPY models: the readable reference
# ----------------------------------------------------------------------------


def _factor(M: np.ndarray) -> np.ndarray:
    """``L`` with ``M = L L^T`` (so ``t M t = |t L|^2`` for row vectors)."""
    return np.linalg.cholesky(M)


def stress_program(disc: Discretization):
    """(S) in CVXPY: returns ``(problem, variables, constraints)``."""
    import cvxpy as cp

    n, k, nc = disc.n_elements, disc.k, disc.n_contact
    m = disc.material
    tau = cp.Variable((n, k), name="tau")
    lam = cp.Variable(nc, name="lam")
    xi = cp.Variable(n, name="xi") if m.hardening > 0 else None
    sqrt_vol = np.sqrt(disc.volumes)[:, None]
    energy = 0.5 * cp.sum_squares(cp.multiply(sqrt_vol, tau @ _factor(m.compliance(disc.dim))))
    if xi is not None:
        energy += 0.5 * cp.sum(cp.multiply(disc.volumes / m.hardening, cp.square(xi)))
    weighted = cp.reshape(cp.multiply(disc.volumes[:, None], tau), (n * k,), order="C")
    cons = {
        "equilibrium": disc.B.T @ weighted - disc.N.T @ lam == 0,
        "force": cp.sum(lam) == disc.force,
        "yield": cp.SOC(m.yield_stress + (xi if xi is not None else 0.0),
                        SQRT_3_2 * (tau @ deviatoric_basis(k)).T, axis=0),
        "sign": lam >= 0,
    }
    prob = cp.Problem(cp.Minimize(energy + disc.psi @ lam), list(cons.values()))
    return prob, {"tau": tau, "xi": xi, "lam": lam}, cons


def displacement_program(disc: Discretization):
    """(D) in CVXPY, with ``p = Q p_hat`` trace-free by construction."""
    import cvxpy as cp

    n, k = disc.n_elements, disc.k
    m = disc.material
    v = cp.Variable(disc.n_free, name="v")
    V = cp.Variable(name="V")
    p_hat = cp.Variable((n, k - 1), name="p")
    kappa = cp.Variable(n, name="kappa")
    eps = cp.reshape(disc.B @ v, (n, k), order="C")
    elastic = eps - p_hat @ deviatoric_basis(k).T
    sqrt_vol = np.sqrt(disc.volumes)[:, None]
    energy = 0.5 * cp.sum_squares(cp.multiply(sqrt_vol, elastic @ _factor(m.stiffness(disc.dim))))
    dissipation = m.yield_stress * (disc.volumes @ kappa)
    if m.hardening > 0:
        dissipation += 0.5 * m.hardening * cp.sum(cp.multiply(disc.volumes, cp.square(kappa)))
    cons = {
        "flow": cp.SOC(kappa, np.sqrt(2.0 / 3.0) * p_hat.T, axis=0),
        "contact": disc.N @ v + disc.psi - V >= 0,
    }
    prob = cp.Problem(cp.Minimize(energy + dissipation - disc.force * V), list(cons.values()))
    return prob, {"v": v, "V": V, "p": p_hat, "kappa": kappa, "eps": eps}, cons


def _cvxpy_solve(prob, options: ConicOptions):
    import cvxpy as cp

    kw = dict(tol_gap_abs=options.tol, tol_gap_rel=options.tol, tol_feas=options.tol,
              tol_ktratio=min(1e-6, options.tol), max_iter=options.max_iter,
              direct_solve_method=options.linear_solver)
    try:
        prob.solve(solver=cp.CLARABEL, verbose=options.verbose, **kw)
    except cp.error.SolverError as exc:
        return Status.FAILED, f"CVXPY/Clarabel: {exc}"
    raw = prob.status
    if raw in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return Status.CONVERGED, f"CVXPY: {raw}"
    if raw in (cp.INFEASIBLE, cp.UNBOUNDED, cp.INFEASIBLE_INACCURATE, cp.UNBOUNDED_INACCURATE):
        return Status.INFEASIBLE, f"CVXPY: {raw} (the force exceeds the limit load)"
    return Status.FAILED, f"CVXPY: {raw}"


def _solver_stats(prob) -> int:
    stats = prob.solver_stats
    return int(stats.num_iters) if stats is not None and stats.num_iters is not None else 0


def solve_conic_cvxpy(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """(S) through CVXPY. CVXPY's equality duals enter its Lagrangian with a plus
    sign, so ``u = -y_equilibrium`` and ``U = -y_force`` as for raw Clarabel."""
    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}

    @with_capped_yield
    def scaled(nd: Discretization):
        t0 = time.perf_counter()
        prob, var, cons = stress_program(nd)
        t1 = time.perf_counter()
        status, msg = _cvxpy_solve(prob, options)
        timings["setup"] += t1 - t0
        timings["solve"] += time.perf_counter() - t1
        if status is not Status.CONVERGED:
            return status, msg, _solver_stats(prob), None, None, None, None, None
        xi = var["xi"].value if var["xi"] is not None else np.zeros(nd.n_elements)
        return (status, msg, _solver_stats(prob), var["tau"].value, xi, -cons["equilibrium"].dual_value,
                -float(cons["force"].dual_value), var["lam"].value)

    return _finish(disc, "conic-cvxpy", scaled, timings)


def solve_conic_displacement(disc: Discretization, options: ConicOptions = ConicOptions()) -> Solution:
    """(D) through CVXPY: ``sigma = C (eps - p)``, ``xi = H kappa``, contact forces
    are the multipliers of the contact inequalities."""
    timings: dict[str, float] = {"setup": 0.0, "solve": 0.0}

    def scaled(nd: Discretization):
        t0 = time.perf_counter()
        prob, var, cons = displacement_program(nd)
        t1 = time.perf_counter()
        status, msg = _cvxpy_solve(prob, options)
        timings["setup"] += t1 - t0
        timings["solve"] += time.perf_counter() - t1
        if status is not Status.CONVERGED:
            return status, msg, _solver_stats(prob), None, None, None, None, None
        m, k = nd.material, nd.k
        p = var["p"].value @ deviatoric_basis(k).T
        sigma = (var["eps"].value - p) @ m.stiffness(nd.dim)
        return (status, msg, _solver_stats(prob), sigma, m.hardening * var["kappa"].value, var["v"].value,
                float(var["V"].value), cons["contact"].dual_value)

    return _finish(disc, "conic-displacement", scaled, timings)
