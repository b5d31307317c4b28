"""Lower bounds on the continuous problem: their options, results, choice and budgets (docs/bounds.md).

Two constructions give ``-J(tau, eta, lam) <= Pi*`` for a statically and plastically
admissible field: the optimum of the equilibrium element, a conic program
(:mod:`elastoplast.bounds.equilibrium`), and the local field built from the P1 solution
(:mod:`elastoplast.bounds.local`). This module holds what they share and what chooses
between them: :class:`LowerBoundOptions`, the results :class:`LowerBound` and
:class:`LimitLowerBound`, :func:`lower_bound_kind`, the program's solver
(:func:`lower_bound_solver`), and the size and memory budgets
(:func:`check_lower_bound_size`, :func:`lower_bound_bytes`, :func:`lower_bound_fits`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastoplast.bounds.static import CERTIFY_TOL, LocalTerms, StaticCertificate, StaticField
from elastoplast.certificate.solution import Status
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization
from elastoplast.options import TIGHTEST_TOL, SolverOptions, option

#: the solvers of the lower-bound programs (:attr:`LowerBoundOptions.solver`)
LOWER_BOUND_SOLVERS = ("clarabel", "scs")
#: the lower bounds :attr:`LowerBoundOptions.kind` chooses from
LOWER_BOUND_KINDS = ("auto", "local", "global")


@dataclass(frozen=True)
class LowerBoundOptions(SolverOptions):
    """Settings of the lower-bound programs (declared and checked like every
    solver's options, :mod:`elastoplast.options`).

    ``tol``: the admissibility certificate's tolerance (:func:`~elastoplast.bounds.static.certify_static`);
    ``ip_tol``, ``max_iter``, ``verbose``, ``time_limit``, ``linear_solver``:
    Clarabel's, as in :class:`~elastoplast.solvers.conic.ConicOptions` (``"auto"``: see
    :data:`~elastoplast.bounds.equilibrium.bound.LOWER_BOUND_FAER_FROM_ELEMENTS_3D`). ``yield_margin``: with H = 0 the energy
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
    ``"global"`` (:func:`~elastoplast.bounds.equilibrium.bound.solve_lower_bound`, the optimum of the equilibrium element; the
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


#: "auto" solves 3D programs from this many elements with SCS, smaller ones and 2D ones
#: with Clarabel (the reference, tight to 1e-9). Measured (benchmarks/bounds/solvers.md,
#: quarter sphere, whole lower bound, one run, 2 shared cores): 600 tetrahedra Clarabel
#: 13.0 s / SCS 5.4 s, 1,080: 33.9 / 16.0, 3,072: 198 / 19.8, the bounds within 1.1e-9
#: relative of each other; below a few hundred tetrahedra both take seconds. In 2D the
#: interior point keeps up (6,400 triangles SCS 1.2x slower, 14,400 1.4x) and SCS's
#: iterations grow with the mesh (125 to 575).
SCS_FROM_ELEMENTS_3D = 500
def lower_bound_solver(disc: Discretization, options: "LowerBoundOptions", limit: bool = False) -> str:
    """The solver ``options.solver`` names; for ``"auto"``, SCS for the energy program on
    3D meshes of at least :data:`SCS_FROM_ELEMENTS_3D` elements, Clarabel otherwise and
    for the limit-load program (``limit``: no quadratic term, where SCS needs thousands
    of iterations; measured on the quarter sphere with H = 0, 288 tetrahedra: Clarabel
    4.3 s, SCS 25 s and 5,050 iterations, the same F_lower to 2e-6)."""
    if options.solver != "auto":
        return options.solver
    return "scs" if not limit and disc.dim == 3 and disc.n_elements >= SCS_FROM_ELEMENTS_3D else "clarabel"


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
    with H = 0 is refused (``InputError('kind')``). Axisymmetric models: the global program
    (``"auto"`` chooses it; ``"local"`` is refused: the local construction in ``tau = r sigma``
    is not built yet)."""
    options = LowerBoundOptions.of(options, "lower_options")
    hardening = disc.material.hardening > 0
    if disc.problem.axisymmetric:
        if options.kind == "local":
            raise InputError("kind", "the local lower bound is not available for axisymmetric models yet: use the "
                                     "global program ('global', or 'auto', which chooses it there)")
        return "global"
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


