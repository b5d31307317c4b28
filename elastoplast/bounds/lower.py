"""Certified lower bounds on the continuous problem: the equilibrium element (docs/bounds.md).

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

from elastoplast.bounds.program import Program, lower_bound_program
from elastoplast.bounds.repair import repair_static
from elastoplast.bounds.static import (
    CERTIFY_TOL,
    LocalTerms,
    PsiWeights,
    StaticCertificate,
    StaticField,
    certify_static,
    local_terms,
    psi_weights,
)
from elastoplast.certificate.solution import Status
from elastoplast.errors import InputError, expect
from elastoplast.fem.axisymmetry import check_not_axisymmetric
from elastoplast.fem.discretize import Discretization, Units, check_hencky, nondimensionalize
from elastoplast.fem.assembly import element_geometry
from elastoplast.fem.material import von_mises
from elastoplast.mesh.topology import FacetTopology, facet_measure
from elastoplast.options import TIGHTEST_TOL, SolverOptions, option
from elastoplast.solvers.backends import (
    ConicAnswer,
    clarabel_settings,
    solve_clarabel,
    solve_scs,
)
from elastoplast.solvers.conic import ConicOptions, elastic_first

#: the solvers of the lower-bound programs (:attr:`LowerBoundOptions.solver`)
LOWER_BOUND_SOLVERS = ("clarabel", "scs")
#: the lower bounds :attr:`LowerBoundOptions.kind` chooses from
LOWER_BOUND_KINDS = ("auto", "local", "global")


@dataclass(frozen=True)
class LowerBoundOptions(SolverOptions):
    """Settings of the lower-bound programs (declared and checked like every
    solver's options, :mod:`elastoplast.options`).

    ``tol``: the admissibility certificate's tolerance (:func:`certify_static`);
    ``ip_tol``, ``max_iter``, ``verbose``, ``time_limit``, ``linear_solver``:
    Clarabel's, as in :class:`~elastoplast.solvers.conic.ConicOptions` (``"auto"``: see
    :data:`LOWER_BOUND_FAER_FROM_ELEMENTS_3D`). ``yield_margin``: with H = 0 the energy
    program is solved with the yield stress ``(1 - yield_margin) sigma_y``, so
    that the repair's correction (of the size of the solver's residuals) cannot
    push a vertex outside the true yield surface; the bound is still valid for
    sigma_y and is weaker by about ``yield_margin`` relative.
    ``psi_subdivisions``: pieces per facet edge for the interval enclosure of an
    ``expression`` obstacle.

    ``solver``: ``"clarabel"`` (interior point, the reference), ``"scs"`` (SCS,
    operator splitting with one factorisation of its KKT matrix, MKL PARDISO where
    installed) or ``"auto"`` (:func:`lower_bound_solver`). Whatever the solver, its
    answer goes through the same repair and certificate, so the choice changes the
    tightness and the time, never the validity. ``scs_eps``: SCS's absolute and
    relative tolerance; ``scs_max_iter`` its iteration limit. With H = 0 the SCS
    program uses the larger margin ``max(yield_margin, SCS_YIELD_MARGIN_PER_EPS *
    scs_eps)`` (its residuals are of the size of ``scs_eps``, not 1e-9).

    ``kind``: which lower bound :func:`~elastoplast.bounds.bracket.lower_bound` computes:
    ``"global"`` (:func:`solve_lower_bound`, the optimum of the equilibrium element; the
    only one with H = 0), ``"local"`` (:func:`~elastoplast.bounds.local.construction.local_lower_bound`,
    built from the P1 solution, H > 0) or ``"auto"`` (:func:`lower_bound_kind`). The
    options above but ``tol`` are the global program's; its size and memory refusals
    (:func:`check_lower_bound_size`) apply to it alone. ``descent``: the local bound's
    steps over all rings after its sweeps (None: :data:`~elastoplast.bounds.local.construction.DESCENT_STEPS`).
    """

    tol: float = option(CERTIFY_TOL, float, "tolerance of the admissibility certificate", lo=TIGHTEST_TOL, hi=1e-8)
    max_iter: int = option(200, int, "interior-point iteration limit", lo=1, hi=10_000)
    ip_tol: float = option(1e-9, float, "Clarabel's gap and feasibility tolerance", lo=1e-14, hi=1e-3)
    verbose: bool = option(False, bool, "Clarabel's own iteration log (on stdout)", persist=False)
    linear_solver: str = option("auto", str, "Clarabel's KKT factorisation", choices=("auto", "qdldl", "faer"))
    yield_margin: float = option(1e-8, float, "H = 0: relative margin below the yield stress", lo=0.0, hi=1e-2)
    psi_subdivisions: int = option(4, int, "expression obstacles: pieces per facet edge of the enclosure", lo=1,
                                   hi=64)
    max_elements: int | None = option(None, int, "largest mesh accepted (none: LOWER_BOUND_MAX_ELEMENTS)", lo=1,
                                      hi=100_000_000, none=True)
    solver: str = option("auto", str, "solver of the lower-bound program", choices=("auto", *LOWER_BOUND_SOLVERS))
    scs_eps: float = option(1e-6, float, "SCS's absolute and relative tolerance", lo=1e-12, hi=1e-2)
    scs_max_iter: int = option(100_000, int, "SCS's iteration limit", lo=1, hi=10_000_000)
    kind: str = option("auto", str, "which lower bound: the global program, the local field, or auto",
                       choices=LOWER_BOUND_KINDS)
    descent: int | None = option(None, int, "the local bound's descent steps over all rings after its sweeps "
                                 "(none: local.DESCENT_STEPS)", lo=0, hi=100_000, none=True)


#: 3D meshes from this many elements use Clarabel's faer factorisation, smaller ones and
#: 2D QDLDL. Measured (benchmarks/bounds/lower.md, quarter sphere, whole lower bound, 2
#: cores, one run): 162 tetrahedra QDLDL 0.8 s / faer 3.1 s; 288: 3.5 / 6.7; 600: 22.0 / 19.4;
#: 1080: 137.2 / 44.7.
LOWER_BOUND_FAER_FROM_ELEMENTS_3D = 600


def lower_bound_kkt_solver(disc: Discretization, options: "LowerBoundOptions") -> str:
    if options.linear_solver != "auto":
        return options.linear_solver
    return "faer" if disc.dim == 3 and disc.n_elements >= LOWER_BOUND_FAER_FROM_ELEMENTS_3D else "qdldl"


#: "auto" solves 3D programs from this many elements with SCS, smaller ones and 2D ones
#: with Clarabel (the reference, tight to 1e-9). Measured (benchmarks/bounds/solvers.md,
#: quarter sphere, whole lower bound, one run, 2 shared cores): 600 tetrahedra Clarabel
#: 13.0 s / SCS 5.4 s, 1,080: 33.9 / 16.0, 3,072: 198 / 19.8, the bounds within 1.1e-9
#: relative of each other; below a few hundred tetrahedra both take seconds. In 2D the
#: interior point keeps up (6,400 triangles SCS 1.2x slower, 14,400 1.4x) and SCS's
#: iterations grow with the mesh (125 to 575).
SCS_FROM_ELEMENTS_3D = 500
#: H = 0 with SCS: the program's yield stress is lowered by this many times ``scs_eps``
SCS_YIELD_MARGIN_PER_EPS = 100.0


def lower_bound_solver(disc: Discretization, options: "LowerBoundOptions", limit: bool = False) -> str:
    """The solver ``options.solver`` names; for ``"auto"``, SCS for the energy program on
    3D meshes of at least :data:`SCS_FROM_ELEMENTS_3D` elements, Clarabel otherwise and
    for the limit-load program (``limit``: no quadratic term, where SCS needs thousands
    of iterations; measured on the quarter sphere with H = 0, 288 tetrahedra: Clarabel
    4.3 s, SCS 25 s and 5,050 iterations, the same F_lower to 2e-6)."""
    if options.solver != "auto":
        return options.solver
    return "scs" if not limit and disc.dim == 3 and disc.n_elements >= SCS_FROM_ELEMENTS_3D else "clarabel"


def yield_margin(solver: str, options: "LowerBoundOptions") -> float:
    """H = 0: the relative margin below sigma_y of the energy program (see :class:`LowerBoundOptions`)."""
    if solver == "scs":
        return min(max(options.yield_margin, SCS_YIELD_MARGIN_PER_EPS * options.scs_eps), 1e-2)
    return options.yield_margin


@dataclass(frozen=True)
class LowerBound:
    """A lower bound ``-J <= Pi*`` from the equilibrium element.

    ``J`` is evaluated exactly at the repaired ``field`` (user units); it is a proof
    when ``certified`` (the certificate passed and the obstacle term is a proved
    over-estimate). ``J_solver`` is the solver's objective, for information
    only. ``local`` holds the per-element and per-facet terms (:class:`LocalTerms`).
    """

    field: StaticField
    J: float
    certified: bool
    certificate: StaticCertificate
    status: Status
    message: str
    timings: dict[str, float]
    local: LocalTerms
    psi_method: str
    J_solver: float
    iterations: int
    repair_residual: float
    contact_zeroed: int = 0
    #: the solver of the program, "clarabel" or "scs" (:attr:`LowerBoundOptions.solver`)
    solver: str = "clarabel"

    @property
    def lower(self) -> float:
        """The bound on ``Pi*`` itself: ``-J``."""
        return -self.J

    @property
    def element_energy(self) -> np.ndarray:
        return self.local.element_energy

    @property
    def element_stress(self) -> np.ndarray:
        """``int_T tau`` per element (Mandel)."""
        return self.local.element_stress

    @property
    def element_mean_stress(self) -> np.ndarray:
        """Mean stress per element (the vertex mean), Mandel."""
        return self.field.tau.mean(axis=1)


@dataclass(frozen=True)
class LimitLowerBound:
    """``F_lower <= F_c`` (perfect plasticity, yield stress sigma_y; hardening ignored)
    from the equilibrium element: a proof when ``certified``. ``F_solver`` is the
    solver's optimum before repair and scaling."""

    F_lower: float
    certified: bool
    field: StaticField
    certificate: StaticCertificate
    status: Status
    message: str
    timings: dict[str, float]
    F_solver: float
    iterations: int
    #: the solver of the program, "clarabel" or "scs" (:attr:`LowerBoundOptions.solver`)
    solver: str = "clarabel"


@dataclass(frozen=True)
class _Setup:
    topo: FacetTopology
    psi: PsiWeights
    nd: Discretization
    units: Units
    grads: np.ndarray


#: the largest meshes the lower bound accepts. The interior point (Clarabel) factors a KKT
#: matrix whose fill grows fast in 3D (about 24 unknowns per element coupled through every
#: facet): 198 s at 3,072 tetrahedra; 2D 47 s at 14,400 triangles. SCS factors once: the 3D
#: default problem (12,288 tetrahedra) in 93 s and 2.2 GB, 24,576 tetrahedra in 357 s and
#: 4.9 GB (benchmarks/bounds/solvers.md, 2 shared cores).
LOWER_BOUND_MAX_ELEMENTS = {2: 100_000, 3: 25_000}
#: the same with Clarabel (the limit-load program, or ``solver="clarabel"``): 3D 8,000
CLARABEL_MAX_ELEMENTS = {2: 100_000, 3: 8_000}
#: peak resident memory of one lower-bound program per element (bytes), from the largest
#: measured peaks less the process's ~0.2 GB base, with a margin for growth: Clarabel 2D
#: 33 kB at 25,600 triangles (benchmarks/bounds/memory.md), 3D 120 kB at 1,080 and 153 kB
#: at 3,072 tetrahedra (benchmarks/bounds/lower.md, solvers.md: its fill grows faster than
#: N); SCS 3D 151 kB at 3,072, 179 kB at 12,288 and 203 kB at 24,576 tetrahedra (5.18 GB,
#: memory.md). Programs run one after another in one process peak higher: the U bracket's
#: two more raised the peak 1.78x in 3D (9.23 GB) and 1.29x in 2D (memory.md).
LOWER_BOUND_BYTES_PER_ELEMENT = {2: 45_000, 3: 250_000}
#: the peak of several programs run one after another in one process (the U bracket,
#: the adaptive loop) over one program's: measured up to 1.78 (above)
SEQUENCE_MEMORY_FACTOR = 2.0


#: peak resident memory of the local lower bound per element (bytes): the process that ran
#: the newton solve and the local bound (default sweeps and descent), less its ~90 MB base,
#: with a margin. Measured (benchmarks/bounds/local.md, 2026-12-02 06:16 UTC, VmHWM): 2D
#: cylinder 7.3 kB at 25,600 triangles (newton alone 2.3 kB); 3D default problem 42 kB at
#: 12,288 tetrahedra (607 MB; 25 kB with the sweeps alone; newton alone 142 MB, the global
#: program 2.2 GB; 601 MB at commit c2a4e13; 37 kB at 98,304 tetrahedra, 3.6 GB): the descent
#: keeps every ring's correction basis, its inverse Hessian and ten L-BFGS pairs. Several in a row peak no higher (the U bracket's three local bounds
#: and two solves at 6,400 triangles: 143 MB against 137 MB for one): no sequence factor.
LOCAL_BOUND_BYTES_PER_ELEMENT = {2: 12_000, 3: 50_000}
#: the same without the descent (the sweeps alone: no frame of ring bases, no inverse
#: Hessians, no L-BFGS pairs), per element above a fixed part: measured (VmHWM, default 3D
#: problem, benchmarks/bounds/local.md at 15ca4eb and a separate run at 98,304 tetrahedra)
#: 378 MB at 12,288 tetrahedra and 1,335 MB at 98,304, 11.1 kB per added tetrahedron (with
#: the descent: 597 MB and 3,651 MB, 35.5 kB); 2D cylinder 231 MB at 25,600 triangles (270 MB
#: with the descent; newton alone 150 MB). 3D re-measured after the sweeps' structures were
#: freed before the lift and the repair and the certificate ran by blocks, and the heap trimmed
#: between phases (benchmarks/bounds/local_scale.md at aaa8bf4; the process also ran the solve
#: to 1e-13 and the upper bound, and holds about 225 MB of libraries before any of it): 621 MB
#: at 98,304 tetrahedra, 1,353 MB at 292,008, 4,158 MB at 1,029,000, at most 4.3 kB per tetrahedron
#: above the libraries. The estimate stays at 16 kB: `adapt` plans with it too, and its process
#: (which also holds the previous mesh and its bounds) peaked at 10.3 GB at 856,682 tetrahedra,
#: 12 kB each, before this change (benchmarks/adapt/local_scale/), not re-measured since.
#: Where the descent would not fit in the memory available but the sweeps alone do, the local
#: bound drops the descent, with a warning (:func:`~elastoplast.bounds.bracket.local_descent`)
LOCAL_SWEEPS_BYTES_PER_ELEMENT = {2: 9_000, 3: 16_000}
#: "auto" (:func:`lower_bound_kind`) takes the global program wherever its size limit
#: (:data:`LOWER_BOUND_MAX_ELEMENTS`) allows, and the local bound above it (H > 0), where
#: the program is refused: the program is the optimum of its space, and in 3D, on the meshes
#: it accepts, the cheaper (one run of ``benchmarks/bounds/local.py``, local.md at commit
#: c2a4e13, global / local with its defaults and the upper bound given: 2D cylinder 10.1 /
#: 5.4 s at 6,400 triangles, 55 / 13 s at 25,600, the local gap 1.10 and 1.03 times the
#: global one; 3D default problem 40 / 73 s at 12,288 tetrahedra, 1.19 times; quarter sphere
#: at 1,080 tetrahedra 3.2 / 10.3 s, 1.25 times; on a cylinder mesh after one adaptive step
#: 1.17 times).
AUTO_GLOBAL_MAX_ELEMENTS = dict(LOWER_BOUND_MAX_ELEMENTS)


def lower_bound_kind(disc: Discretization, options: "LowerBoundOptions | None" = None) -> str:
    """``"global"`` or ``"local"``: the lower bound ``options.kind`` asks for on ``disc``.
    ``"auto"``: the global program when H = 0 (the only lower bound there) or the mesh has at
    most :data:`AUTO_GLOBAL_MAX_ELEMENTS` elements, the local bound otherwise. ``"local"``
    with H = 0 is refused (``InputError('kind')``)."""
    options = LowerBoundOptions.of(options, "lower_options")
    hardening = disc.material.hardening > 0
    if options.kind == "local" and not hardening:
        raise InputError("kind", "the local lower bound needs hardening > 0 (with H = 0 only the global program "
                                 "keeps the stresses within the yield surface): choose 'global' or 'auto'")
    if options.kind != "auto":
        return options.kind
    return "global" if not hardening or disc.n_elements <= AUTO_GLOBAL_MAX_ELEMENTS[disc.dim] else "local"


def lower_bound_bytes(dim: int, n_elements: int, kind: str = "global", descent: bool = True) -> int:
    """Estimated peak memory of one lower bound of ``kind`` on ``n_elements`` elements
    (the global program's, or the local bound's with its solve: with its descent, or
    ``descent`` False the sweeps alone)."""
    if kind == "global":
        per = LOWER_BOUND_BYTES_PER_ELEMENT
    else:
        per = LOCAL_BOUND_BYTES_PER_ELEMENT if descent else LOCAL_SWEEPS_BYTES_PER_ELEMENT
    return int(per[dim]) * int(n_elements)


def lower_bound_fits(dim: int, factor: float = SEQUENCE_MEMORY_FACTOR, kind: str = "global") -> int | None:
    """The most elements whose lower bounds of ``kind`` (global programs: ``factor`` times the
    estimate of one; local bounds: one, the sweeps alone, as
    :func:`~elastoplast.bounds.bracket.local_descent` runs it where the descent does not
    fit) fit in the memory available now
    (:func:`elastoplast.limits.available_memory`), or None where that is unknown."""
    from elastoplast.limits import available_memory

    limit, _ = available_memory()
    if limit is None:
        return None
    if kind == "global":
        return int(limit // (factor * lower_bound_bytes(dim, 1)))
    return int(limit // lower_bound_bytes(dim, 1, kind, descent=False))


def check_lower_bound_size(disc: Discretization, options: LowerBoundOptions, limit: bool = False,
                           factor: float = 1.0) -> None:
    """Refuse a mesh the lower-bound program cannot finish (``options.max_elements``, or
    :data:`LOWER_BOUND_MAX_ELEMENTS` and with Clarabel :data:`CLARABEL_MAX_ELEMENTS`),
    naming the size, or whose program would not fit in memory
    (:func:`lower_bound_bytes`, times ``factor`` for several programs in a row), with the
    estimate; ``limit`` for the limit-load program."""
    solver = lower_bound_solver(disc, options, limit)
    largest = options.max_elements or (CLARABEL_MAX_ELEMENTS if solver == "clarabel" else LOWER_BOUND_MAX_ELEMENTS)[disc.dim]
    if disc.n_elements > largest:
        raise InputError("mesh", f"{disc.n_elements:,} elements: the equilibrium-element lower bound with {solver} is "
                                 f"limited to {largest:,} in {disc.dim}D (its cost grows fast, see "
                                 "benchmarks/bounds/solvers.md); coarsen the mesh, or let 'elastoplast adapt' place "
                                 "the elements (from Python, LowerBoundOptions(max_elements=...) raises the limit)")
    from elastoplast.limits import check_memory

    check_memory(int(factor * lower_bound_bytes(disc.dim, disc.n_elements)), "mesh",
                 f"the equilibrium-element lower bound with {solver} ({disc.n_elements:,} elements)",
                 "coarsen the mesh, or let 'elastoplast adapt' place the elements")


def lower_bound_setup(disc: Discretization, options: LowerBoundOptions, force: float | None = None, limit: bool = False) -> _Setup:
    check_lower_bound_size(disc, options, limit)
    topo = disc.facet_topology
    psi = psi_weights(disc, topo, options.psi_subdivisions)
    nd, units = nondimensionalize(disc if force is None else disc.with_force(force))
    _, grads = element_geometry(disc.mesh)
    return _Setup(topo, psi, nd, units, grads * units.length)


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
    """User-unit field from program unknowns (eta left at zero)."""
    n, d, k = s.nd.n_elements, s.nd.dim, s.nd.k
    S = s.units.stress
    tau = x[prog.cols["tau"]].reshape(n, d + 1, k) / prog.weights[:, None, None] * S
    lam = (x[prog.cols["lam"]] / prog.lam_weights * S).reshape(-1, d)
    return StaticField(tau=tau, eta=np.zeros((n, d + 1)), contact_facets=s.topo.contact_facets, lam=lam,
                       force=float(force))


def repaired_field(disc: Discretization, s: _Setup, prog: Program, x: np.ndarray) -> tuple[StaticField, float, int]:
    """:func:`repair_static`, then (H > 0) eta raised where the corrected tau needs it."""
    x, resid, zeroed = repair_static(prog, x)
    field = program_field(s, prog, x, disc.force)
    if prog.cols["eta"] is not None:
        vm = von_mises(field.tau.reshape(-1, disc.k)).reshape(field.eta.shape)
        eta = x[prog.cols["eta"]].reshape(field.eta.shape) / prog.weights[:, None] * s.units.stress
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
    check_not_axisymmetric(disc.problem, "the lower bound")
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
        prog = progs[with_yield] = lower_bound_program(nd_, s.topo, s.grads, q_nd, with_yield=with_yield)
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
