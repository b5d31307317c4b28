"""External solvers on the same instances, each answer certified before it counts.

Three conic solvers take the stress form (S) exactly as :func:`~elastoplast.io.export.export`
writes it, built in memory by the same builder (:func:`~elastoplast.io.export.stress_form`,
then :func:`~elastoplast.io.export.clarabel_form`), solve it at their own default
tolerances and hand their primal and dual vectors to
:func:`~elastoplast.io.export.answer_from_solution`, which maps them back to
``(sigma, xi, u, U, lambda)`` in the problem's units:

* :func:`run_clarabel_export`: Clarabel's interior point (``clarabel-export``);
* :func:`run_scs_export`: SCS, a first-order splitting method (``scs-export``);
* :func:`run_ecos_export`: ECOS, an interior point for LP/SOCP only: the energy sits in
  the rotated cone of the export (converted to a second-order cone), never in ``P``
  (``ecos-export``).

One more, on a different problem: :func:`run_osqp_elastic` solves the *elastic* contact
problem (no yield cones: the QP ``min 1/2 [tau, tau]_A + psi . lam`` over equilibrium,
the force balance and ``lam >= 0``) with OSQP. Its answer is the answer of (2.1) only
when nothing yields; an answer that yields is FAILED (``yields: the elastic contact QP
does not apply``).

Whatever the solver says, the status is the certificate's
(:func:`~elastoplast.certificate.solution.make_solution`, the same KKT certificate as
every method's): CONVERGED when every residual is at most ``options.tol``; otherwise
the solver's iteration or time limit, its infeasibility certificate, or FAILED. The
solver's own status word goes into the message. No Newton polishing: the answer is the
external solver's own.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.fem.discretize import Discretization, check_hencky, nondimensionalize
from elastoplast.fem.material import Material, von_mises
from elastoplast.io.export import answer_from_solution, clarabel_form, stress_form
from elastoplast.options import MAX_ITER_CEILING, SolverOptions, option
from elastoplast.solvers.backends import solve_clarabel, solve_scs
from elastoplast.fem.stress_form import element_weights
from elastoplast.solvers.conic import stress_form_data
from elastoplast.solvers.contact import osqp_polish_key
from elastoplast.solvers.loop import check_inputs, within_tolerance
from elastoplast.solvers.registry import Method

# ----------------------------------------------------------------------------
# options
# ----------------------------------------------------------------------------

#: the solvers' own defaults (Clarabel 0.11 ``DefaultSettings``, SCS 3.2 ``eps_abs = eps_rel``,
#: ECOS 2.0 ``feastol = abstol = reltol``, OSQP 1.x ``eps_abs = eps_rel``), quoted in messages
CLARABEL_DEFAULT_TOL = 1e-8
SCS_DEFAULT_EPS = 1e-4
ECOS_DEFAULT_TOL = 1e-8


@dataclass(frozen=True)
class ClarabelExportOptions(SolverOptions):
    """``clarabel-export``: Clarabel on the exported (S).

    ``tol`` (the certificate's, 1e-4 by default): an interior point stopped at its
    default gap of 1e-8 leaves dual displacements whose error shows in the worst
    element's strains, measured 3e-6..2e-5 on the test meshes (docs/methods.md,
    "External solvers"). ``ip_tol``: Clarabel's gap and feasibility tolerances
    (none: Clarabel's defaults, 1e-8). ``max_iter``: Clarabel's default 200.
    ``energy``: the energy in the rotated cone of the export (``"cone"``) or in ``P``
    (``"quadratic"``)."""

    tol: float = option(1e-4, float, "bound on every relative KKT residual of the answer", lo=1e-13, hi=1e-2)
    max_iter: int = option(200, int, "interior-point iteration limit", lo=1, hi=10_000)
    ip_tol: float | None = option(None, float, "Clarabel's gap and feasibility tolerance (none: its default 1e-8)",
                                  lo=1e-14, hi=1e-2, none=True)
    energy: str = option("quadratic", str, "the energy in P (quadratic) or in a rotated cone (cone)",
                         choices=("quadratic", "cone"))
    verbose: bool = option(False, bool, "Clarabel's own iteration log (on stdout)", persist=False)


@dataclass(frozen=True)
class SCSExportOptions(SolverOptions):
    """``scs-export``: SCS on the exported (S).

    SCS stops when its residuals are below ``eps`` relative to the data (none: its
    default 1e-4); the displacements, read off its duals, are then accurate to about
    that, and the certificate's per-element ratio amplifies it in the worst element:
    ``tol`` is 1e-2 (:data:`~elastoplast.options.LOOSEST_TOL`) by default, and
    ``eps = 1e-6`` brings the certificate to about 1e-4. ``max_iter``: SCS's default
    100,000. ``energy`` as for ``clarabel-export``."""

    tol: float = option(1e-2, float, "bound on every relative KKT residual of the answer", lo=1e-13, hi=1e-2)
    max_iter: int = option(100_000, int, "SCS iteration limit", lo=1, hi=MAX_ITER_CEILING)
    eps: float | None = option(None, float, "SCS's eps_abs = eps_rel (none: its default 1e-4)", lo=1e-12, hi=1e-1,
                               none=True)
    energy: str = option("quadratic", str, "the energy in P (quadratic) or in a rotated cone (cone)",
                         choices=("quadratic", "cone"))
    verbose: bool = option(False, bool, "SCS's own iteration log (on stdout)", persist=False)


@dataclass(frozen=True)
class ECOSExportOptions(SolverOptions):
    """``ecos-export``: ECOS on the exported (S), the energy in the rotated cone
    (ECOS has no quadratic objective).

    ``ip_tol``: ECOS's ``feastol``, ``abstol`` and ``reltol`` (none: its defaults,
    1e-8). ``tol`` 1e-3 by default: at its default tolerances ECOS's dual displacements
    are off by up to 2e-4 relative (measured 1.6e-5..2.4e-4 on five test meshes, the
    whole field, not one element); ``ip_tol = 1e-10`` brings that to about 5e-7.
    ``max_iter``: ECOS's default 100. ECOS cannot be stopped by a clock:
    ``time_limit`` is checked when it returns (an answer not certified by then is
    ``time_limit``), as the other methods check it between iterations."""

    tol: float = option(1e-3, float, "bound on every relative KKT residual of the answer", lo=1e-13, hi=1e-2)
    max_iter: int = option(100, int, "interior-point iteration limit", lo=1, hi=10_000)
    ip_tol: float | None = option(None, float, "ECOS's feastol = abstol = reltol (none: its default 1e-8)",
                                  lo=1e-14, hi=1e-2, none=True)
    verbose: bool = option(False, bool, "ECOS's own iteration log (on stdout)", persist=False)


@dataclass(frozen=True)
class OSQPElasticOptions(SolverOptions):
    """``osqp-elastic``: OSQP on the elastic contact QP (no yield).

    OSQP is ADMM: it stops at ``eps`` (``eps_abs = eps_rel``, 1e-7 here; OSQP's own
    default 1e-3 leaves the displacements, its duals, far too coarse for a certificate),
    then ``polish`` solves the KKT system on the contact set it found, which lands on the
    QP's solution to rounding when that set is right. ``tol`` 1e-6 as for the package's
    own methods. ``max_iter``: 10,000 ADMM iterations (OSQP's default 4000)."""

    max_iter: int = option(10_000, int, "ADMM iteration limit", lo=1, hi=MAX_ITER_CEILING)
    eps: float = option(1e-7, float, "OSQP's eps_abs = eps_rel", lo=1e-12, hi=1e-1)
    polish: bool = option(True, bool, "OSQP's solution polishing on the contact set it found")
    verbose: bool = option(False, bool, "OSQP's own iteration log (on stdout)", persist=False)


# ----------------------------------------------------------------------------
# (S) as exported, in memory
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ExportedProgram:
    """(S) in Clarabel's and SCS's convention, minimise ``1/2 x'Px + q'x`` subject to
    ``A x + s = b`` with ``s`` in ``zero`` equality rows, ``nonnegative`` rows and the
    second-order cones ``second_order``, in that order; ``meta`` is what
    :func:`~elastoplast.io.export.answer_from_solution` reads of an export's sidecar."""

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    zero: int
    nonnegative: int
    second_order: list[int]
    meta: dict[str, Any]

    def clarabel_cones(self) -> list:
        import clarabel

        cones = [clarabel.ZeroConeT(self.zero)] if self.zero else []
        cones += [clarabel.NonnegativeConeT(self.nonnegative)] if self.nonnegative else []
        return cones + [clarabel.SecondOrderConeT(k) for k in self.second_order]


def exported_stress_form(disc: Discretization, energy: str = "cone") -> ExportedProgram:
    """(S) exactly as ``export(disc, path, "npz", "S", energy=energy)`` writes it, with the
    part of its sidecar that maps answers back (variables, rows, units, sizes)."""
    built = stress_form(disc, energy)
    cf = clarabel_form(built.program, built.P)
    row_of = cf["row_of"]
    rows = {name: [int(row_of[a]), int(row_of[a]) + (b - a)] for name, (a, b) in built.rows.items()}
    s = built.scaling
    meta = {
        "form": "S", "energy": energy,
        "mesh": {"dim": disc.dim, "n_elements": int(disc.n_elements), "n_free_dofs": int(disc.n_free),
                 "n_contact_nodes": int(disc.n_contact)},
        "units": {key: s[key] for key in ("stress", "length", "displacement", "force", "energy", "E")},
        "variables": built.variables, "rows": rows,
        "duals": {"dual_to_displacement": 1.0 / s["force"]},
    }
    return ExportedProgram(sp.csc_matrix(cf["P"]), np.asarray(cf["q"], dtype=float), sp.csc_matrix(cf["A"]),
                           np.asarray(cf["b"], dtype=float), int(cf["zero"]), int(cf["nonnegative"]),
                           list(cf["second_order"]), meta)


# ----------------------------------------------------------------------------
# the verdict: the certificate decides
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Raw:
    """An external solver's answer in its own words: ``status`` is what its status word
    would mean in the package's terms (used only when the certificate does not pass)."""

    solver: str
    word: str
    status: Status
    x: np.ndarray
    z: np.ndarray
    iterations: int


def zero_solution(disc: Discretization, method: str, status: Status, message: str, iterations: int,
                  timings: dict[str, float]) -> Solution:
    """A certified 'solution' of zeros, for a solver that produced nothing usable."""
    z = np.zeros
    return make_solution(disc, method=method, status=status, sigma=z((disc.n_elements, disc.k)),
                         xi=z(disc.n_elements), u_free=z(disc.n_free), U=0.0, contact_force=z(disc.n_contact),
                         iterations=iterations, timings=timings, message=message)


def judged(disc: Discretization, sol: Solution, tol: float, fallback: Status) -> Solution:
    """``sol`` (built with status CONVERGED) with the certificate's verdict at ``tol``:
    CONVERGED when every residual is at most ``tol`` (unless ``make_solution`` found
    non-finite values or strains beyond small strains: that FAILED stands); otherwise
    ``fallback``, the meaning of the solver's status word (its iteration or time limit,
    infeasibility), or FAILED when the solver claimed success."""
    worst = sol.kkt.worst
    if within_tolerance(sol.kkt, tol):
        if sol.status is not Status.CONVERGED:
            return sol
        return replace(sol, message=f"{sol.message}; certified KKT residual {worst:.1e} <= tol {tol:g}")
    status = Status.FAILED if fallback is Status.CONVERGED else fallback
    return replace(sol, status=status, message=f"{sol.message}; certified KKT residual {worst:.1e} above tol {tol:g}")


def finish_export(disc: Discretization, method: str, prog: ExportedProgram, raw: Raw, tol: float,
                  timings: dict[str, float]) -> Solution:
    """Map ``raw`` back (:func:`~elastoplast.io.export.answer_from_solution`), certify, judge."""
    message = f"{raw.solver}: {raw.word} after {raw.iterations} iterations"
    usable = (raw.x.size == prog.A.shape[1] and raw.z.size == prog.A.shape[0]
              and np.all(np.isfinite(raw.x)) and np.all(np.isfinite(raw.z)))
    if not usable:
        status = raw.status if raw.status is Status.INFEASIBLE else Status.FAILED
        return zero_solution(disc, method, status, f"{message}; no usable answer", raw.iterations, timings)
    ans = answer_from_solution(disc, raw.x, raw.z, prog.meta)
    with np.errstate(all="ignore"):
        sol = make_solution(disc, method=method, status=Status.CONVERGED, sigma=ans.sigma, xi=ans.xi,
                            u_free=ans.u_free, U=ans.U, contact_force=ans.contact_force, iterations=raw.iterations,
                            timings=timings, message=message)
    return judged(disc, sol, tol, raw.status)


def announce(options: SolverOptions, text: str) -> None:
    """One progress line on stderr (``progress=True``), as the package's own interior point."""
    if options.progress:
        print(text, file=sys.stderr, flush=True)


def run_exported(disc: Discretization, method: str, options: SolverOptions, energy: str, solve) -> Solution:
    """Build (S), run ``solve(prog) -> Raw``, certify; timings ``setup``, ``solve``, ``total``."""
    t0 = time.perf_counter()
    prog = exported_stress_form(disc, energy)
    t1 = time.perf_counter()
    announce(options, f"{method}: {prog.A.shape[1]} variables, {prog.A.shape[0]} rows ...")
    raw = solve(prog)
    t2 = time.perf_counter()
    announce(options, f"{method}: {raw.word} after {raw.iterations} iterations, {t2 - t0:.1f} s")
    timings = {"setup": t1 - t0, "solve": t2 - t1}
    sol = finish_export(disc, method, prog, raw, options.tol, timings)
    return replace(sol, timings={**sol.timings, "total": time.perf_counter() - t0})


# ----------------------------------------------------------------------------
# Clarabel, SCS, ECOS on (S)
# ----------------------------------------------------------------------------


def run_clarabel_export(disc: Discretization, options: ClarabelExportOptions = ClarabelExportOptions()) -> Solution:
    """Clarabel on the exported (S), at Clarabel's default tolerances unless ``ip_tol``."""
    import clarabel

    options = check_inputs(disc, options, ClarabelExportOptions)

    def solve(prog: ExportedProgram) -> Raw:
        s = clarabel.DefaultSettings()
        s.verbose = options.verbose
        s.max_iter = options.max_iter
        if options.time_limit is not None:
            s.time_limit = options.time_limit
        if options.ip_tol is not None:
            s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = options.ip_tol
            s.tol_ktratio = min(s.tol_ktratio, options.ip_tol)
        res = solve_clarabel(prog.P, prog.q, prog.A, prog.b, prog.clarabel_cones(), s)
        return Raw("Clarabel", res.raw, res.status, res.x, res.z, res.iterations)

    return run_exported(disc, "clarabel-export", options, options.energy, solve)


def run_scs_export(disc: Discretization, options: SCSExportOptions = SCSExportOptions()) -> Solution:
    """SCS on the exported (S), at SCS's default ``eps`` (1e-4) unless ``eps``."""
    options = check_inputs(disc, options, SCSExportOptions)
    eps = SCS_DEFAULT_EPS if options.eps is None else options.eps

    def solve(prog: ExportedProgram) -> Raw:
        res = solve_scs(prog.P, prog.q, prog.A, prog.b, prog.clarabel_cones(), eps, options.max_iter,
                        options.verbose, options.time_limit)
        return Raw("SCS", res.raw, res.status, res.x, res.z, res.iterations)

    return run_exported(disc, "scs-export", options, options.energy, solve)


#: ECOS's ``exitFlag`` (ecos/include/ecos.h): 0 optimal, 10 "close to optimal"
#: (ECOS_INACC_OFFSET + 0), 1 and 11 primal infeasible, 2 and 12 dual infeasible,
#: -1 iteration limit, -2 numerics, -3 left the cone, -4 interrupted, -7 fatal
ECOS_STATUS = {0: Status.CONVERGED, 10: Status.CONVERGED, 1: Status.INFEASIBLE, 11: Status.INFEASIBLE,
               -1: Status.MAX_ITERATIONS}


def run_ecos_export(disc: Discretization, options: ECOSExportOptions = ECOSExportOptions()) -> Solution:
    """ECOS on the exported (S) with the energy in the rotated cone: an SOCP
    ``min c'x  s.t.  A_eq x = b_eq, h - G x in (R+ x SOC ...)``. ECOS's duals ``y``
    (equalities) and ``z`` (cones) obey ``c + A_eq'y + G'z = 0``: stacked, they are
    Clarabel's ``z`` of the same rows."""
    options = check_inputs(disc, options, ECOSExportOptions)
    import ecos

    def solve(prog: ExportedProgram) -> Raw:
        if prog.P.nnz:
            raise ValueError("ECOS takes no quadratic objective: the energy must be in the cone")
        A = prog.A.tocsr()
        z0 = prog.zero
        settings: dict[str, Any] = {"max_iters": options.max_iter, "verbose": options.verbose}
        if options.ip_tol is not None:
            settings.update(feastol=options.ip_tol, abstol=options.ip_tol, reltol=options.ip_tol)
        dims = {"l": prog.nonnegative, "q": list(prog.second_order), "e": 0}
        res = ecos.solve(prog.q, sp.csc_matrix(A[z0:]), prog.b[z0:], dims, sp.csc_matrix(A[:z0]), prog.b[:z0],
                         **settings)
        info = res["info"]
        flag = int(info["exitFlag"])
        z = np.concatenate([np.asarray(res["y"], dtype=float), np.asarray(res["z"], dtype=float)])
        return Raw("ECOS", f"{info['infostring']} (exitFlag {flag})", ECOS_STATUS.get(flag, Status.FAILED),
                   np.asarray(res["x"], dtype=float), z, int(info["iter"]))

    sol = run_exported(disc, "ecos-export", options, "cone", solve)
    limit, spent = options.time_limit, sol.timings.get("total", 0.0)
    if limit is not None and spent > limit and not sol.converged:
        return replace(sol, status=Status.TIME_LIMIT,
                       message=f"{sol.message}; ran {spent:.3g} s, past time_limit {limit:g} s (checked on return)")
    return sol


# ----------------------------------------------------------------------------
# OSQP on the elastic contact QP
# ----------------------------------------------------------------------------

#: OSQP's status words (1.x and 0.6 alike) that are not success
OSQP_STATUS = {"solved": Status.CONVERGED, "solved inaccurate": Status.CONVERGED,
               "maximum iterations reached": Status.MAX_ITERATIONS, "run time limit reached": Status.TIME_LIMIT,
               "primal infeasible": Status.INFEASIBLE, "primal infeasible inaccurate": Status.INFEASIBLE}

YIELDS = "yields: the elastic contact QP does not apply"


def osqp_solve(P, q, A, l, u, **settings):
    """OSQP's ``setup`` then ``solve`` (without the exception OSQP 1.x may raise at a
    limit); returns ``(x, y, status word, iterations)``, ``x`` and ``y`` copied."""
    import osqp

    solver = osqp.OSQP()
    solver.setup(sp.csc_matrix(P), q, sp.csc_matrix(A), l, u, **settings)
    try:
        res = solver.solve(raise_error=False)
    except TypeError:  # osqp 0.6: no raise_error
        res = solver.solve()
    return np.array(res.x, dtype=float), np.array(res.y, dtype=float), str(res.info.status), int(res.info.iter)


def elastic_copy(disc: Discretization) -> Discretization:
    """``disc`` with an infinite yield stress: the elastic contact problem."""
    m = disc.material
    return replace(disc, problem=replace(disc.problem, material=Material(m.E, m.nu, np.inf, m.hardening)))


def run_osqp_elastic(disc: Discretization, options: OSQPElasticOptions = OSQPElasticOptions()) -> Solution:
    """OSQP on the elastic contact problem: (S) without yield cones,
    ``min 1/2 sum_T |T| tau_T A tau_T + psi . lam`` subject to equilibrium, the force
    balance and ``lam >= 0`` (``conic.stress_form_data(nd, with_yield=False)`` in the
    working units), ``u = -y_equilibrium``, ``U = -y_force`` (OSQP's ``P x + q + A'y = 0``,
    Clarabel's convention).

    Valid only when the elastic answer stays within the yield surface. The answer is
    certified as the elastic problem's (an infinite yield stress) and as (2.1)'s. If
    the elastic certificate passes ``options.tol`` and the von Mises stress exceeds
    ``material.yield_stress`` anywhere, the status is FAILED with the message
    :data:`YIELDS`. Otherwise the certificate of (2.1) at ``options.tol`` decides, as
    for every method (an unfinished ADMM run is then ``max_iterations`` or
    ``time_limit``)."""
    options = check_inputs(disc, options, OSQPElasticOptions)
    check_hencky(disc, "osqp-elastic")
    t0 = time.perf_counter()
    nd, units = nondimensionalize(disc)
    P, q, A, b, _, lay = stress_form_data(nd, with_yield=False)
    n_eq = nd.n_free + 1
    lower = np.concatenate([b[:n_eq], np.full(b.size - n_eq, -np.inf)])
    settings: dict[str, Any] = {"eps_abs": options.eps, "eps_rel": options.eps, "max_iter": options.max_iter,
                                osqp_polish_key(): options.polish, "verbose": options.verbose}
    if options.time_limit is not None:
        settings["time_limit"] = options.time_limit
    t1 = time.perf_counter()
    announce(options, f"osqp-elastic: ADMM on {A.shape[1]} variables, {A.shape[0]} rows ...")
    x, y, word, iters = osqp_solve(sp.triu(P, format="csc"), q, A, lower, b, **settings)
    t2 = time.perf_counter()
    announce(options, f"osqp-elastic: {word} after {iters} iterations, {t2 - t0:.1f} s")
    timings = {"setup": t1 - t0, "solve": t2 - t1}
    method, message = "osqp-elastic", f"OSQP: {word} after {iters} iterations"
    status = OSQP_STATUS.get(word, Status.FAILED)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return zero_solution(disc, method, Status.INFEASIBLE if status is Status.INFEASIBLE else Status.FAILED,
                             f"{message}; no usable answer", iters, timings)
    w = element_weights(nd)
    sigma = units.stress * x[lay["tau"]].reshape(nd.n_elements, nd.k) / w[:, None]
    arrays = dict(sigma=sigma, xi=np.zeros(nd.n_elements), u_free=-units.displacement * y[lay["eq"]],
                  U=-units.displacement * float(y[lay["force"]]), contact_force=units.force * x[lay["lam"]])
    with np.errstate(all="ignore"):
        elastic = make_solution(elastic_copy(disc), method=method, status=Status.CONVERGED, iterations=iters,
                                timings=timings, message=message, **arrays)
        sol = make_solution(disc, method=method, status=Status.CONVERGED, iterations=iters, timings=timings,
                            message=f"{message}; the elastic QP's own certificate {elastic.kkt.worst:.1e}", **arrays)
    sol = replace(sol, timings={**sol.timings, "total": time.perf_counter() - t0})
    vm, sy = von_mises(sigma), disc.material.yield_stress
    over = vm > sy * (1.0 + options.tol)
    if np.any(over) and within_tolerance(elastic.kkt, options.tol):  # the elastic QP's certified answer yields
        return replace(sol, status=Status.FAILED,
                       message=f"{YIELDS}: the von Mises stress reaches {vm.max():.4g} > material.yield_stress = "
                               f"{sy:g} in {int(over.sum())} element(s) (use conic, newton or uzawa); {sol.message}")
    return judged(disc, sol, options.tol, status)


# ----------------------------------------------------------------------------
# the methods, registered through the entry-point group elastoplast.methods
# (pyproject.toml): the registry lives below io/ and does not import it
# ----------------------------------------------------------------------------

CLARABEL_EXPORT = Method("clarabel-export", run_clarabel_export, ClarabelExportOptions,
                         "Clarabel on the exported (S), certified")
SCS_EXPORT = Method("scs-export", run_scs_export, SCSExportOptions, "SCS on the exported (S), certified")
ECOS_EXPORT = Method("ecos-export", run_ecos_export, ECOSExportOptions,
                     "ECOS on the exported (S) (the energy in a cone), certified")
OSQP_ELASTIC = Method("osqp-elastic", run_osqp_elastic, OSQPElasticOptions,
                      "OSQP on the elastic contact QP (failed if the answer yields)")
