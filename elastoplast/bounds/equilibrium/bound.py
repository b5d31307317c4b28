"""The global lower bound: the optimum of the equilibrium element, repaired and certified (docs/bounds.md).

A statically and plastically admissible field ``(tau, eta, lam)`` of the continuous
problem gives ``-J(tau, eta, lam) <= Pi*`` (weak duality, docs/bounds.md), with

    J = 1/2 int_Omega (A tau : tau + eta^2 / H) + int_Gamma0 lam psi.

The field used here is the equilibrium element of lower-bound limit analysis: ``tau``
and ``eta`` linear on each element (vertex values), discontinuous between elements,
``lam`` linear on each contact facet (vertex values, discontinuous between facets), and

* ``div tau = 0`` in every element (d linear rows per element);
* traction continuity at each vertex of each interior facet (linear tractions agree
  on a facet iff they agree at its d vertices);
* on boundary facets, by the facet groups of :class:`~elastoplast.problem.definition.Boundary`
  (see :func:`facet_topology`): clamped, no condition; symmetry (``fix_component``
  c), ``t_j = 0`` for ``j != c``; contact (Γ0), ``tau n = lam e_d``; every other
  boundary facet (also those on ``x_d = 0`` outside Γ0) free, ``tau n = 0``;
* ``int_Gamma0 lam = F`` (linear lam: vertex mean times facet area), ``lam >= 0`` at
  the contact-facet vertices;
* ``(tau, eta) in D`` at every element vertex (D is convex, so then everywhere);
  one second-order cone per element vertex.

The objective is integrated exactly: the P1 mass matrix ``int_T b_a b_b = |T|(1 +
delta_ab)/((d+1)(d+2))`` for the energy and ``int_f lam psi_over`` for the obstacle,
where ``psi_over >= psi`` on every contact facet (:func:`psi_weights`).

**The continuum problem bounded** is the one defined by the *facets* of the groups:
Γ0, the clamped part and the symmetry planes are unions of mesh facets. The discrete
P1 problem (2.1) fixes dofs at the *nodes* of the groups, which is the same
continuum problem seen through P1 functions (a node shared by a clamped and a free
facet is fixed in P1 because the clamped facet's trace is zero there). Group facets
that are interior facets of the mesh are ignored: continuity across them is
enforced anyway, which only shrinks the admissible set (the bound stays valid).

**Proof, not estimate.** A solver's objective is never the bound. The solver's
answer is repaired (:func:`repair_static`: an exact minimum-norm correction onto the
linear equality rows, ``lam >= 0`` kept exactly, yield restored vertex by vertex), J
is then evaluated exactly (:func:`dual_energy`), and an independent admissibility
check (:func:`certify_static`) must pass for the bound to be reported as guaranteed.

**Solvers.** The program is solved by Clarabel (interior point, the reference) or SCS
(operator splitting: one factorisation, then cheap iterations), chosen by
:func:`lower_bound_solver`. In 3D the interior point's repeated KKT factorisations
dominate (each element's unknowns form a clique coupled through every facet); SCS
factors once and reached Clarabel's optimum to 1e-9 relative at its default tolerance
(benchmarks/bounds/solvers.md). Since every answer is repaired and certified, the
solver changes the tightness of the bound and the time, never its validity.

Limit mode (H = 0, docs/bounds.md): :func:`static_limit_load` maximises F over the same
constraints with eta = 0; a certified answer is ``F_lower <= F_c``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from elastoplast.bounds.equilibrium.program import Program, Ring, lower_bound_program
from elastoplast.bounds.equilibrium.repair import repair_static
from elastoplast.bounds.lower import LimitLowerBound, LowerBound, LowerBoundOptions, check_lower_bound_size, lower_bound_solver
from elastoplast.bounds.static import (PsiWeights, StaticField, certify_static, local_terms, psi_weights,
                                       ring_vertex_stress, vertex_radii)
from elastoplast.certificate.solution import Status
from elastoplast.errors import InputError, expect
from elastoplast.fem.axisymmetry import check_not_axisymmetric
from elastoplast.fem.discretize import Discretization, Units, check_hencky, nondimensionalize
from elastoplast.fem.assembly import element_geometry
from elastoplast.fem.material import von_mises
from elastoplast.mesh.topology import FacetTopology, facet_measure
from elastoplast.solvers.backends import (
    ConicAnswer,
    clarabel_settings,
    solve_clarabel,
    solve_scs,
)
from elastoplast.solvers.conic import ConicOptions, elastic_first


#: 3D meshes from this many elements use Clarabel's faer factorisation, smaller ones and
#: 2D QDLDL. Measured (benchmarks/bounds/lower.md, quarter sphere, whole lower bound, 2
#: cores, one run): 162 tetrahedra QDLDL 0.8 s / faer 3.1 s; 288: 3.5 / 6.7; 600: 22.0 / 19.4;
#: 1080: 137.2 / 44.7.
LOWER_BOUND_FAER_FROM_ELEMENTS_3D = 600


def lower_bound_kkt_solver(disc: Discretization, options: "LowerBoundOptions") -> str:
    if options.linear_solver != "auto":
        return options.linear_solver
    return "faer" if disc.dim == 3 and disc.n_elements >= LOWER_BOUND_FAER_FROM_ELEMENTS_3D else "qdldl"


#: H = 0 with SCS: the program's yield stress is lowered by this many times ``scs_eps``
SCS_YIELD_MARGIN_PER_EPS = 100.0


def yield_margin(solver: str, options: "LowerBoundOptions") -> float:
    """H = 0: the relative margin below sigma_y of the energy program (see :class:`LowerBoundOptions`)."""
    if solver == "scs":
        return min(max(options.yield_margin, SCS_YIELD_MARGIN_PER_EPS * options.scs_eps), 1e-2)
    return options.yield_margin


@dataclass(frozen=True)
class _Setup:
    topo: FacetTopology
    psi: PsiWeights
    nd: Discretization
    units: Units
    grads: np.ndarray
    ring: Ring | None = None


def lower_bound_setup(disc: Discretization, options: LowerBoundOptions, force: float | None = None, limit: bool = False) -> _Setup:
    check_lower_bound_size(disc, options, limit)
    topo = disc.facet_topology
    psi = psi_weights(disc, topo, options.psi_subdivisions)
    nd, units = nondimensionalize(disc if force is None else disc.with_force(force))
    area, grads = element_geometry(disc.mesh)
    ring = None
    if disc.problem.axisymmetric:  # radii and areas in the program's length unit
        ring = Ring(r=vertex_radii(disc) / units.length, area=area / units.length**2)
    return _Setup(topo, psi, nd, units, grads * units.length, ring)


def _scs(prog: Program, options: LowerBoundOptions) -> ConicAnswer:
    """SCS on the program; SCS and Clarabel share the convention ``A x + s = b``.

    The slack of the rows ``-lam + s = 0`` (``s >= 0``, ``contact_sign_rows``) is lam
    projected onto ``lam >= 0``, with exact zeros where the contact is inactive: a
    better start for the repair than x's own lam, which is off by SCS's residual (tiny
    values of either sign would each cost the repair another round). The repair makes
    the answer exactly admissible whatever SCS's residuals (of the size of ``scs_eps``).
    """
    res = solve_scs(prog.P, prog.q, prog.A, prog.b, prog.cones, options.scs_eps, options.scs_max_iter,
                    options.verbose, options.time_limit)
    lam = prog.cols["lam"]
    x = res.x.copy()
    x[lam] = res.s[prog.n_eq: prog.n_eq + lam.stop - lam.start]
    return replace(res, x=x)


def solve_program(disc: Discretization, prog: Program, options: LowerBoundOptions, solver: str) -> ConicAnswer:
    """``prog`` solved by ``solver`` ("clarabel" or "scs")."""
    if solver == "scs":
        return _scs(prog, options)
    conic = ConicOptions(ip_tol=options.ip_tol, max_iter=options.max_iter, verbose=options.verbose,
                         time_limit=options.time_limit)
    settings = clarabel_settings(conic, lower_bound_kkt_solver(disc, options))
    return solve_clarabel(prog.P, prog.q, prog.A, prog.b, prog.cones, settings)


def program_field(s: _Setup, prog: Program, x: np.ndarray, force: float) -> StaticField:
    """User-unit field from program unknowns (eta left at zero). Axisymmetric models: the
    unknowns are the vertex stresses ``s_a`` and pressures p (:mod:`.program`); the field
    is ``tau_a = r_a s_a`` (hoop slot ``r_a sigma_thth``, sigma_thth the mean hoop slot off
    the axis), ``lam = r p``, exactly zero on the axis."""
    n, d, k = s.nd.n_elements, s.nd.dim, s.nd.k
    S = s.units.stress
    tau = x[prog.cols["tau"]].reshape(n, d + 1, k) / prog.weights[:, None, None] * S
    lam = (x[prog.cols["lam"]] / prog.lam_weights * S).reshape(-1, d)
    if s.ring is None:
        return StaticField(tau=tau, eta=np.zeros((n, d + 1)), contact_facets=s.topo.contact_facets, lam=lam,
                           force=float(force))
    off = s.ring.off_axis
    hoop = np.where(off, tau[..., 2], 0.0).sum(axis=1) / off.sum(axis=1)
    r = s.ring.r * s.units.length
    tau = np.where(off[..., None], r[..., None] * tau, 0.0)
    tau[..., 2] = np.where(off, r, 0.0) * hoop[:, None]
    ci = s.topo.contact_index
    r_contact = np.maximum(r[s.topo.boundary_elements[ci][:, None], s.topo.boundary_vertices[ci]], 0.0)
    return StaticField(tau=tau, eta=np.zeros((n, d + 1)), contact_facets=s.topo.contact_facets, lam=r_contact * lam,
                       force=float(force), hoop=hoop)


def repaired_field(disc: Discretization, s: _Setup, prog: Program, x: np.ndarray) -> tuple[StaticField, float, int]:
    """:func:`repair_static`, then (H > 0) eta raised where the corrected tau needs it."""
    x, resid, zeroed = repair_static(prog, x)
    field = program_field(s, prog, x, disc.force)
    if prog.cols["eta"] is not None:
        eta = x[prog.cols["eta"]].reshape(field.eta.shape) / prog.weights[:, None] * s.units.stress
        if s.ring is None:
            vm = von_mises(field.tau.reshape(-1, disc.k)).reshape(field.eta.shape)
        else:  # yield on the vertex stresses off the axis; eta has no part on the axis
            sigma, off = ring_vertex_stress(disc, field)
            vm = von_mises(sigma.reshape(-1, disc.k)).reshape(field.eta.shape)
            eta = np.where(off, eta, 0.0)
        field = replace(field, eta=np.maximum(eta, vm - disc.material.yield_stress))
    return field, resid, zeroed


def solve_lower_bound(disc: Discretization, options: LowerBoundOptions = LowerBoundOptions()) -> LowerBound:
    """The best equilibrium-element field on the mesh and its certified bound ``-J <= Pi*``.

    Steps: the program of :func:`lower_bound_program` in O(1) units (a large yield
    stress is first tried as inactive, as for (S), see
    :func:`~elastoplast.solvers.conic.elastic_first`); the repair of :func:`repair_static`;
    H > 0: ``eta = max(eta_solver, sqrt(3/2)|dev tau| - sigma_y)`` at every vertex,
    raised only where the corrected tau needs it (the solver's eta may be negative
    at vertices off the yield surface: the P1 mass matrix couples the vertices, and
    ``(tau, eta)`` with ``sigma_y + eta >= sqrt(3/2)|dev tau|`` is admissible whatever
    the sign of eta, see :class:`StaticCertificate`); H = 0: the
    program used ``(1 - margin) sigma_y`` (``yield_margin``, larger with SCS, see
    :class:`LowerBoundOptions`); J evaluated exactly; the certificate. The program
    is solved by :func:`lower_bound_solver`'s choice.

    Raises :class:`InputError` (``load.force``) when H = 0 and the solver proves
    that no field of the equilibrium element carries F.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_hencky(disc, "the lower bound")
    options = LowerBoundOptions.of(options)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    s = lower_bound_setup(disc, options)
    solver = lower_bound_solver(disc, options)
    m = disc.material
    nd = s.nd
    if m.hardening == 0:
        margin = yield_margin(solver, options)
        nd = replace(nd, problem=replace(nd.problem, material=replace(nd.material, yield_stress=nd.material.yield_stress * (1 - margin))))
    q_nd = s.psi.q / (s.units.displacement * s.units.length ** (disc.dim - 1))
    timings["setup"] = time.perf_counter() - t0
    progs: dict[bool, Program] = {}

    @elastic_first
    def scaled(nd_: Discretization, with_yield: bool):
        t1 = time.perf_counter()
        prog = progs[with_yield] = lower_bound_program(nd_, s.topo, s.grads, q_nd, with_yield=with_yield, ring=s.ring)
        t2 = time.perf_counter()
        ans = solve_program(disc, prog, options, solver)
        timings["assemble"] = timings.get("assemble", 0.0) + t2 - t1
        timings["solve"] = timings.get("solve", 0.0) + time.perf_counter() - t2
        tau = ans.x[prog.cols["tau"]].reshape(-1, nd_.k) / np.repeat(prog.weights, nd_.dim + 1)[:, None]
        return ans.status, ans, ans.iterations, tau, with_yield

    status, ans, iters, _, with_yield = scaled(nd)
    prog, x = progs[with_yield], ans.x
    if status is Status.INFEASIBLE or not np.all(np.isfinite(x)):
        if m.hardening == 0 and ans.infeasible:
            raise InputError("load.force", f"no stress field of the equilibrium element on this mesh carries F = {disc.force:g} "
                             "within the yield surface (H = 0): F is above this mesh's lower-bound limit load "
                             "(see static_limit_load); reduce the force, refine the mesh or give hardening > 0")
        raise InputError("load.force", f"the lower-bound program failed ({ans.label}); no bound")

    t1 = time.perf_counter()
    field, resid, zeroed = repaired_field(disc, s, prog, x)
    timings["repair"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    cert = certify_static(disc, field, options.tol)
    local = local_terms(disc, field, s.psi, s.topo)
    J = float(local.element_energy.sum() + local.facet_psi_work.sum())
    timings["certify"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0

    certified = cert.passed and s.psi.rigorous
    msg = [ans.label, f"repair residual {resid:.1e}, {zeroed} contact pressure(s) fixed at 0"]
    if not cert.passed:
        msg.append(f"NOT certified: {', '.join(f'{k} {getattr(cert, k):.1e}' for k in cert.failed)} above {cert.tol:.0e}")
    if not s.psi.rigorous:
        msg.append(f"NOT certified: obstacle term is the {s.psi.method}")
    energy_unit = s.units.force * s.units.displacement
    return LowerBound(field=field, J=J, certified=certified, certificate=cert, status=status, message="; ".join(msg),
                      timings=timings, local=local, psi_method=s.psi.method, J_solver=ans.objective * energy_unit,
                      iterations=iters, repair_residual=resid, contact_zeroed=zeroed, solver=solver)


def static_limit_load(disc: Discretization, options: LowerBoundOptions = LowerBoundOptions()) -> LimitLowerBound:
    """Maximise F over the equilibrium element with eta = 0 (docs/bounds.md).

    The program is solved in units where the stress unit is sigma_y. Repair: with F
    held at the solver's value, the projection of :func:`repair_static`; then the
    whole field (tau, lam, F) is scaled by ``s = min(1, min_vertices sigma_y /
    (sqrt(3/2)|dev tau|))``, which keeps every linear condition (they are homogeneous
    in (tau, lam, F)) and puts every vertex inside the yield surface. The certified
    answer is ``F_lower = s F``.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_hencky(disc, "the limit load")
    check_not_axisymmetric(disc.problem, "the limit load")
    options = LowerBoundOptions.of(options)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    m = disc.material
    area = facet_measure(disc.mesh.points[disc.facet_topology.contact_facets]).sum()
    s = lower_bound_setup(disc, options, force=m.yield_stress * area, limit=True)  # stress unit = sigma_y
    prog = lower_bound_program(s.nd, s.topo, s.grads, np.zeros_like(s.psi.q), limit=True)
    timings["setup"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    solver = lower_bound_solver(disc, options, limit=True)
    ans = solve_program(disc, prog, options, solver)
    status, x, iters = ans.status, ans.x, ans.iterations
    timings["solve"] = time.perf_counter() - t1
    F_solver = float(x[prog.cols["force"]] * s.units.force) if x.size else float("nan")
    empty = StaticField(np.zeros((disc.n_elements, disc.dim + 1, disc.k)), np.zeros((disc.n_elements, disc.dim + 1)),
                        s.topo.contact_facets, np.zeros(s.topo.contact_facets.shape), 0.0)
    if ans.unbounded:
        msg = (f"{ans.label}: the equilibrium element carries arbitrarily large F within the yield surface "
               "(no limit load; e.g. a confined contact zone)")
        return LimitLowerBound(float("inf"), False, empty, certify_static(disc.with_force(1.0), replace(empty, force=1.0)),
                               Status.INFEASIBLE, msg, timings, F_solver, iters, solver)
    if status is Status.INFEASIBLE or not np.all(np.isfinite(x)):
        raise InputError("boundary", f"the limit-load program failed ({ans.label})")
    t1 = time.perf_counter()
    x, resid, zeroed = repair_static(prog, x)
    F = float(x[prog.cols["force"]] * s.units.force)
    field = program_field(s, prog, x, F)
    vm = von_mises(field.tau.reshape(-1, disc.k))
    scale = min(1.0, m.yield_stress / vm.max(initial=0.0)) if vm.max(initial=0.0) > 0 else 1.0
    field = replace(field, tau=field.tau * scale, lam=field.lam * scale, force=F * scale)
    timings["repair"] = time.perf_counter() - t1
    if not field.force > 0:  # the solver stopped before any positive load (e.g. at its time limit)
        timings["total"] = time.perf_counter() - t0
        return LimitLowerBound(0.0, False, empty, certify_static(disc.with_force(1.0), replace(empty, force=1.0)),
                               status, f"{ans.label}: no positive load found, F_lower = 0 is all it shows", timings,
                               F_solver, iters, solver)
    cert = certify_static(disc.with_force(field.force), field, options.tol)
    timings["total"] = time.perf_counter() - t0
    msg = f"{ans.label}; repair residual {resid:.1e}, yield scaling 1 - {1 - scale:.1e}"
    if not cert.passed:
        msg += f"; NOT certified: {', '.join(f'{k} {getattr(cert, k):.1e}' for k in cert.failed)} above {cert.tol:.0e}"
    return LimitLowerBound(field.force, cert.passed, field, cert, status, msg, timings, F_solver, iters, solver)
