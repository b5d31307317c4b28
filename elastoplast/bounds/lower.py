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
import scipy.sparse as sp

from elastoplast.problem.options import TIGHTEST_TOL, SolverOptions, option
from elastoplast.solvers.conic import _CLARABEL_STATUS, ConicOptions, clarabel_settings, elastic_first, yield_cone_rows
from elastoplast.fem.discretize import _STRAIN_ROWS, Discretization, Units, _element_geometry, nondimensionalize
from elastoplast.errors import InputError, expect
from elastoplast.fem.material import n_components, von_mises
from elastoplast.mesh.base import Mesh
from elastoplast.problem.definition import Boundary
from elastoplast.certificate.solution import Status
from elastoplast.mesh.topology import FacetTopology, facet_measure, facet_topology, outward_normals

#: every residual of :func:`certify_static` must be at most this (relative to its stated scale)
CERTIFY_TOL = 1e-12


# ----------------------------------------------------------------------------
# facet topology
# ----------------------------------------------------------------------------


# ----------------------------------------------------------------------------
# geometry
# ----------------------------------------------------------------------------


def traction_operator(v: np.ndarray) -> np.ndarray:
    """``N(v) (..., d, k)`` with ``N(v) tau = tau v`` for Mandel vectors ``tau``.

    It is the transpose of the Mandel symmetric gradient of ``u (x) v``
    (``_STRAIN_ROWS``), since ``tau : sym(u (x) v) = (tau v) . u``. Hence also
    ``div tau = sum_a N(grad b_a) tau_a`` for a linear field with vertex values
    ``tau_a``. In plane strain the tau33 column is zero.
    """
    d = v.shape[-1]
    out = np.zeros(v.shape[:-1] + (d, n_components(d)))
    for c, terms in enumerate(_STRAIN_ROWS[d]):
        for comp, der, w in terms:
            out[..., comp, c] += w * v[..., der]
    return out


def mass_matrix(dim: int) -> np.ndarray:
    """``int_S b_a b_b / |S| = (1 + delta_ab) / ((n+1)(n+2))`` on a ``dim``-simplex (n = dim)."""
    return (np.ones((dim + 1, dim + 1)) + np.eye(dim + 1)) / ((dim + 1) * (dim + 2))


# ----------------------------------------------------------------------------
# the obstacle term
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class PsiWeights:
    """``q (n_cf, d)`` with ``q_fa >= int_f psi b_a`` (b_a the facet's P1 basis), so that
    ``int_f lam psi <= sum_a q_fa lam_a`` for ``lam >= 0``; ``rigorous`` says whether
    the inequality is proved, ``method`` how q was obtained."""

    q: np.ndarray
    rigorous: bool
    method: str


def psi_weights(disc: Discretization, topo: FacetTopology, subdivisions: int = 4) -> PsiWeights:
    """Safe obstacle weights on the contact facets.

    Sphere, cylinder, paraboloid and flat ψ are convex (the sphere on
    ``|x' - c| < R``, which :meth:`Obstacle.psi` enforces at the facet vertices, hence
    on the facets), so the P1 interpolant is above ψ on each facet and
    ``q_fa = int_f I_h psi b_a = |f| sum_b M_ab psi_b`` exactly. For an ``expression``
    ψ nothing is known about convexity: ψ is enclosed by interval arithmetic on each
    of ``subdivisions**(d-1)`` pieces of every facet (:mod:`elastoplast.problem.intervals`),
    and ``q_fa = sum_pieces max_piece psi * int_piece b_a``.
    """
    mesh, obstacle = disc.mesh, disc.problem.obstacle
    nodes = topo.contact_facets
    X = mesh.points[nodes][:, :, :-1]
    d = disc.dim
    measure = facet_measure(mesh.points[nodes])
    if obstacle.shape != "expression":
        psi = obstacle.psi(X.reshape(-1, d - 1), field="obstacle").reshape(-1, d)
        return PsiWeights(measure[:, None] * psi @ mass_matrix(d - 1), True, "P1 interpolant of a convex psi")
    from elastoplast.problem.intervals import enclose_on_simplices

    q, reason = enclose_on_simplices(obstacle, X, measure, subdivisions)
    if q is None:
        psi = obstacle.psi(X.reshape(-1, d - 1), field="obstacle").reshape(-1, d)
        return PsiWeights(measure[:, None] * psi @ mass_matrix(d - 1), False,
                          f"P1 interpolant (not an over-estimate: {reason})")
    return PsiWeights(q, True, f"interval enclosure on {subdivisions ** (d - 1)} pieces per facet")


# ----------------------------------------------------------------------------
# the field, its energy and its certificate
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class StaticField:
    """A candidate stress field of the equilibrium element, in user units.

    ``tau (n_el, d+1, k)`` Mandel vertex values (in the order of ``mesh.cells``; in
    plane strain with tau33), ``eta (n_el, d+1)`` hardening stresses at the vertices,
    ``contact_facets (n_cf, d)`` node indices of the Γ0 facets (sorted per facet),
    ``lam (n_cf, d)`` contact pressure at their vertices (in that node order),
    ``force`` the F it balances.
    """

    tau: np.ndarray
    eta: np.ndarray
    contact_facets: np.ndarray
    lam: np.ndarray
    force: float


@dataclass(frozen=True)
class LocalTerms:
    """Per-element and per-contact-facet pieces of J and of the weak-duality gap.

    ``element_energy`` = ``1/2 int_T (A tau:tau + eta^2/H)``; ``element_stress`` =
    ``int_T tau`` (= |T| times the vertex mean, Mandel), so ``int_T tau : eps(v) =
    element_stress . eps_T(v)`` for P1 v; ``facet_force`` = ``int_f lam``;
    ``facet_psi_work`` = ``sum_a q_fa lam_a >= int_f lam psi``. J is the sum of
    ``element_energy`` and ``facet_psi_work``.
    """

    element_energy: np.ndarray
    element_stress: np.ndarray
    facet_force: np.ndarray
    facet_psi_work: np.ndarray


def local_terms(disc: Discretization, field: StaticField, psi: PsiWeights | None = None,
                topo: FacetTopology | None = None) -> LocalTerms:
    """The terms of :class:`LocalTerms`, integrated exactly with the P1 mass matrices."""
    d, m = disc.dim, disc.material
    topo = facet_topology(disc.mesh, disc.problem.boundary) if topo is None else topo
    psi = psi_weights(disc, topo) if psi is None else psi
    M = mass_matrix(d)
    A = m.compliance(d)
    tau = np.asarray(field.tau, dtype=float)
    energy = np.einsum("ab,eai,ij,ebj->e", M, tau, A, tau)
    if m.hardening > 0:
        energy = energy + np.einsum("ab,ea,eb->e", M, field.eta, field.eta) / m.hardening
    measure = facet_measure(disc.mesh.points[field.contact_facets])
    return LocalTerms(
        element_energy=0.5 * disc.volumes * energy,
        element_stress=disc.volumes[:, None] * tau.mean(axis=1),
        facet_force=measure * field.lam.mean(axis=1),
        facet_psi_work=np.einsum("fa,fa->f", psi.q, field.lam),
    )


def dual_energy(disc: Discretization, field: StaticField, psi: PsiWeights | None = None) -> float:
    """``J = 1/2 int (A tau:tau + eta^2/H) + int lam psi_over``, integrated exactly
    (eta is ignored when H = 0; :func:`certify_static` requires it to vanish then)."""
    t = local_terms(disc, field, psi)
    return float(t.element_energy.sum() + t.facet_psi_work.sum())


@dataclass(frozen=True)
class StaticCertificate:
    """Admissibility residuals of a :class:`StaticField`, each relative to a stated scale.

    ``scale`` is the stress scale ``s = max(max_vertices |tau|, max lam, F/|Γ0|)``
    (|.| the Frobenius norm of the full tensor) and ``t = tau n`` the traction on a
    facet with unit outward normal n at a facet vertex:

    * ``equilibrium``: ``max_T |div tau_T| h_T / s`` (h_T the smallest height of T);
    * ``traction_jump``: ``max |t_T + t_T'| / s`` over the vertices of interior facets;
    * ``free_traction``: ``max |t_j| / s`` over free facets (no group);
    * ``symmetry_traction``: ``max |t_j| / s``, j not fixed, on facets with fixed components;
    * ``contact_normal``: ``max |t_d - lam| / s`` and ``contact_tangential``: ``max |t_j| / s``
      (j != d, not fixed) on Γ0 facets;
    * ``force_balance``: ``|int_Γ0 lam - F| / F`` with F the problem's load ``disc.force``;
    * ``contact_sign``: ``max(-lam, 0) / s``;
    * ``yield_excess``: ``max(sqrt(3/2)|dev tau| - sigma_y - eta, 0) / sigma_y`` at every
      element vertex;
    * ``hardening``: ``max |eta| / sigma_y`` when H = 0 (the energy ``eta^2 / H`` forces
      eta = 0), 0 when H > 0. The sign of eta is free: weak duality needs
      ``W(eps) >= tau:eps - 1/2 A tau:tau - eta^2/(2H)``, and for eta < 0 with
      ``sqrt(3/2)|dev tau| <= sigma_y + eta`` the pair ``(tau, 0)`` is in D and gives a
      larger right-hand side, so ``yield_excess`` is the only condition on eta.

    ``passed`` when every residual is at most ``tol``.
    """

    equilibrium: float
    traction_jump: float
    free_traction: float
    symmetry_traction: float
    contact_normal: float
    contact_tangential: float
    force_balance: float
    contact_sign: float
    yield_excess: float
    hardening: float
    scale: float
    tol: float

    def as_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in RESIDUALS}

    @property
    def worst(self) -> float:
        return max(self.as_dict().values())

    @property
    def failed(self) -> tuple[str, ...]:
        """Names of the residuals above the tolerance."""
        return tuple(k for k, v in self.as_dict().items() if not v <= self.tol)

    @property
    def passed(self) -> bool:
        return not self.failed


RESIDUALS = ("equilibrium", "traction_jump", "free_traction", "symmetry_traction", "contact_normal",
             "contact_tangential", "force_balance", "contact_sign", "yield_excess", "hardening")


def _vmax(a: np.ndarray) -> float:
    return float(np.max(a, initial=0.0))


def certify_static(disc: Discretization, field: StaticField, tol: float = CERTIFY_TOL) -> StaticCertificate:
    """Check that ``field`` is statically and plastically admissible (docs/bounds.md).

    Uses only the mesh, the facet groups, the material and the field: facet normals
    and measures come from edge vectors (:func:`outward_normals`), not from the
    program's gradient-based rows, and whatever produced the field plays no part.

    Why ``tol = 1e-12`` is safe: an exactly admissible field, stored in double
    precision, has residuals of a few units of round-off (each residual sums at
    most 2(d+1)k products of numbers bounded by the scale s: well below 1e-14 s).
    The repaired fields of :func:`repair_static` measure at 1e-16..1e-14. A field
    within 1e-12 s of every linear condition is such a stored field up to a
    perturbation of relative size 1e-12, which changes J by the same relative
    amount, far below the discretisation gaps that the bounds measure. A solver's
    raw output (residuals at its tolerance, 1e-10..1e-6) fails.
    """
    mesh, m = disc.mesh, disc.material
    topo = facet_topology(mesh, disc.problem.boundary)
    tau = np.asarray(field.tau, dtype=float)
    eta = np.asarray(field.eta, dtype=float)
    lam = np.asarray(field.lam, dtype=float)
    F = float(disc.force)  # the problem's load, not the one the field claims
    if not np.array_equal(np.asarray(field.contact_facets), topo.contact_facets):
        raise InputError("field.contact_facets", "do not match the contact facets of the problem")

    # equilibrium: div of the linear field from the barycentric gradients
    _, grads = _element_geometry(mesh)
    div = np.einsum("eadk,eak->ed", traction_operator(grads), tau)
    h = 1.0 / np.linalg.norm(grads, axis=2).max(axis=1)

    contact_measure = facet_measure(mesh.points[topo.contact_facets])
    # Mandel vectors are orthonormal coordinates: their norm is the tensor's Frobenius norm
    s = max(_vmax(np.linalg.norm(tau, axis=-1)), _vmax(lam), F / contact_measure.sum())

    def traction(elements, vertices, nodes):
        nrm, _ = outward_normals(mesh, elements, nodes)
        t_vertex = tau[elements[:, None], vertices]  # (m, d, k)
        return np.einsum("mdk,mak->mad", traction_operator(nrm), t_vertex)

    jump = traction(topo.interior_elements[:, 0], topo.interior_vertices[:, 0], topo.interior_nodes) + traction(
        topo.interior_elements[:, 1], topo.interior_vertices[:, 1], topo.interior_nodes)
    tb = np.abs(traction(topo.boundary_elements, topo.boundary_vertices, topo.boundary_nodes))  # (n_bf, d vertices, d)
    zero = topo.zero_traction[:, None, :]
    free = ~topo.fixed.any(axis=1) & ~topo.contact
    sym = topo.fixed.any(axis=1) & ~topo.contact
    tb_signed = traction(topo.boundary_elements[topo.contact], topo.boundary_vertices[topo.contact],
                         topo.contact_facets)
    vm = von_mises(tau.reshape(-1, disc.k)).reshape(eta.shape)
    return StaticCertificate(
        equilibrium=_vmax(np.linalg.norm(div, axis=1) * h) / s,
        traction_jump=_vmax(np.linalg.norm(jump, axis=2)) / s,
        free_traction=_vmax(np.where(zero, tb, 0.0)[free]) / s,
        symmetry_traction=_vmax(np.where(zero, tb, 0.0)[sym]) / s,
        contact_normal=_vmax(np.abs(tb_signed[:, :, -1] - lam)) / s,
        contact_tangential=_vmax(np.where(zero, tb, 0.0)[topo.contact]) / s,
        force_balance=abs(float(contact_measure @ lam.mean(axis=1)) - F) / F,
        contact_sign=_vmax(-lam) / s,
        yield_excess=_vmax(vm - m.yield_stress - eta) / m.yield_stress,
        hardening=0.0 if m.hardening > 0 else _vmax(np.abs(eta)) / m.yield_stress,
        scale=s,
        tol=tol,
    )


# ----------------------------------------------------------------------------
# the conic program (energy-normalised unknowns, O(1) units)
# ----------------------------------------------------------------------------


#: the solvers of the lower-bound programs (:attr:`LowerBoundOptions.solver`)
LOWER_BOUND_SOLVERS = ("clarabel", "scs")


@dataclass(frozen=True)
class LowerBoundOptions(SolverOptions):
    """Settings of the lower-bound programs (declared and checked like every
    solver's options, :mod:`elastoplast.problem.options`).

    ``tol``: the admissibility certificate's tolerance (:func:`certify_static`);
    ``ip_tol``, ``max_iter``, ``verbose``, ``time_limit``, ``linear_solver``:
    Clarabel's, as in :class:`~elastoplast.solvers.conic.ConicOptions` (``"auto"``: see
    :data:`FAER_FROM_ELEMENTS_3D`). ``yield_margin``: with H = 0 the energy
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


#: 3D meshes from this many elements use Clarabel's faer factorisation, smaller ones and
#: 2D QDLDL. Measured (benchmarks/bounds/lower.md, quarter sphere, whole lower bound, 2
#: cores, one run): 162 tetrahedra QDLDL 0.8 s / faer 3.1 s; 288: 3.5 / 6.7; 600: 22.0 / 19.4;
#: 1080: 137.2 / 44.7.
FAER_FROM_ELEMENTS_3D = 600


def _kkt_solver(disc: Discretization, options: "LowerBoundOptions") -> str:
    if options.linear_solver != "auto":
        return options.linear_solver
    return "faer" if disc.dim == 3 and disc.n_elements >= FAER_FROM_ELEMENTS_3D else "qdldl"


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


def _yield_margin(solver: str, options: "LowerBoundOptions") -> float:
    """H = 0: the relative margin below sigma_y of the energy program (see :class:`LowerBoundOptions`)."""
    if solver == "scs":
        return min(max(options.yield_margin, SCS_YIELD_MARGIN_PER_EPS * options.scs_eps), 1e-2)
    return options.yield_margin


@dataclass(frozen=True)
class Program:
    """Clarabel data ``(P, q, A, b, cones)``; the first ``n_eq`` rows of A are the
    equality rows; ``weights`` are the element weights ``w_T = sqrt(|T|/mean|T|)`` of
    the unknowns ``tau_hat = w_T tau``, ``eta_hat = w_T eta``, ``lam_hat = w_T lam``
    (T the element of the contact facet); ``cols`` the column ranges by name."""

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    cones: list
    n_eq: int
    weights: np.ndarray
    lam_weights: np.ndarray
    cols: dict


def _block_coo(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray):
    """Flatten broadcastable index/value arrays, dropping structural zeros."""
    rows, cols, vals = (np.broadcast_to(a, np.broadcast_shapes(rows.shape, cols.shape, vals.shape)).ravel()
                        for a in (rows, cols, vals))
    keep = vals != 0.0
    return rows[keep], cols[keep], vals[keep]


def equality_rows(nd: Discretization, topo: FacetTopology, grads: np.ndarray, n_cols: int,
                  lam_col: int, force_col: int | None):
    """The equality rows ``A x = b`` in energy-normalised unknowns, every row a force.

    With ``G_ea = (|T_e| / w_e) N(grad b_a)`` (d x k; note ``|f_i| n_i / d = -|T| grad b_i``
    for the facet opposite vertex i, n its outward unit normal):

    * element e: ``sum_a G_ea tau_hat_ea = 0`` (``|T| div tau = 0``);
    * interior facet, at each facet vertex: ``G_{T,i} tau_hat_{T,a} + G_{T',i'}
      tau_hat_{T',a'} = 0`` (the outward tractions times ``|f|/d`` cancel);
    * boundary facet opposite vertex i of T, at facet vertex a, component j:
      ``(G_{T,i} tau_hat_{T,a})_j = 0`` where the traction must vanish, and
      ``(G_{T,i} tau_hat_{T,a})_d + (|f|/d) / w_T lam_hat_a = 0`` on Γ0;
    * ``sum_f (|f|/d) sum_a lam_a = F`` (or ``- F_hat`` in column ``force_col``).
    """
    d, k, n = nd.dim, nd.k, nd.n_elements
    w = np.sqrt(nd.volumes / nd.volumes.mean())
    G = (nd.volumes / w)[:, None, None, None] * traction_operator(grads)  # (n, d+1, d, k)
    ck = np.arange(k)
    cr = np.arange(d)

    def tau_cols(e, a):
        return ((e * (d + 1) + a) * k)[..., None, None] + ck  # (..., 1, k)

    parts = []
    # element equilibrium
    e = np.arange(n)[:, None]
    a = np.arange(d + 1)[None, :]
    parts.append(_block_coo((e * d)[:, :, None, None] + cr[:, None], tau_cols(e, a), G))
    row = n * d
    # interior facets
    IE, IL, IV = topo.interior_elements, topo.interior_local, topo.interior_vertices
    n_if = IE.shape[0]
    f = np.arange(n_if)[:, None, None]
    j = np.arange(d)[None, None, :]
    rows = row + ((f * d + j) * d)[..., None, None] + cr[:, None]  # (n_if, 1, d, d, 1)
    Gf = G[IE, IL][:, :, None]  # (n_if, 2, 1, d, k)
    parts.append(_block_coo(rows, tau_cols(IE[:, :, None], IV), Gf))
    row += n_if * d * d
    # boundary facets
    BE, BL, BV = topo.boundary_elements, topo.boundary_local, topo.boundary_vertices
    n_bf = BE.shape[0]
    cond = topo.zero_traction.copy()
    cond[:, -1] |= topo.contact
    keep = np.broadcast_to(cond[:, None, :], (n_bf, d, d))  # (facet, vertex, component)
    row_id = np.where(keep, row + np.cumsum(keep.ravel()).reshape(keep.shape) - 1, -1)
    Gb = G[BE, BL][:, None]  # (n_bf, 1, d, k)
    r_, c_, v_ = _block_coo(row_id[..., None], tau_cols(BE[:, None], BV), Gb)
    parts.append((r_[r_ >= 0], c_[r_ >= 0], v_[r_ >= 0]))
    row += int(keep.sum())
    # contact pressure in the vertical rows of the Γ0 facets, and the force balance
    ci = topo.contact_index
    share = (nd.volumes[BE[ci]] * np.linalg.norm(grads[BE[ci], BL[ci]], axis=1) / w[BE[ci]])  # (|f|/d) / w_T
    lam_cols = lam_col + np.arange(ci.size * d).reshape(-1, d)
    parts.append((row_id[ci, :, -1].ravel(), lam_cols.ravel(), np.repeat(share, d)))
    parts.append((np.full(lam_cols.size, row), lam_cols.ravel(), np.repeat(share, d)))
    b = np.zeros(row + 1)
    if force_col is None:
        b[row] = nd.force
    else:
        parts.append((np.array([row]), np.array([force_col]), np.array([-1.0])))
    r, c, v = (np.concatenate(x) for x in zip(*parts))
    return sp.csc_matrix((v, (r, c)), shape=(row + 1, n_cols)), b


def lower_bound_program(nd: Discretization, topo: FacetTopology, grads: np.ndarray, q_psi: np.ndarray,
                        limit: bool = False, with_yield: bool = True) -> Program:
    """The equilibrium-element program on the O(1) problem ``nd`` (see
    :func:`~elastoplast.fem.discretize.nondimensionalize`); ``grads`` the barycentric
    gradients in its length unit, ``q_psi`` the obstacle weights in its units.

    Energy mode: minimise ``1/2 sum_T sum_ab M_ab (tau_hat_a A tau_hat_b + eta_hat_a
    eta_hat_b / H) + sum q lam`` (the exact J: ``|T| / w_T^2 = 1`` per element).
    Limit mode: minimise ``-F_hat`` with eta = 0 and no energy. Cones: ``lam_hat >= 0``,
    and ``sqrt(3/2)|dev tau_hat_a| <= w_T sigma_y + eta_hat_a`` at each element vertex
    (the per-element cone of (S), :func:`~elastoplast.solvers.conic.yield_cone_rows`, applied
    to a copy of ``nd`` whose 'elements' are the element vertices).
    """
    import clarabel

    from elastoplast.solvers.conic import contact_sign_rows

    d, k, n, m = nd.dim, nd.k, nd.n_elements, nd.material
    nv = n * (d + 1)
    has_eta = not limit and m.hardening > 0
    n_lam = topo.contact_index.size * d
    eta_col = nv * k
    lam_col = eta_col + (nv if has_eta else 0)
    n_cols = lam_col + n_lam + (1 if limit else 0)
    force_col = n_cols - 1 if limit else None
    w = np.sqrt(nd.volumes / nd.volumes.mean())
    lam_w = np.repeat(w[topo.boundary_elements[topo.contact_index]], d)

    A_eq, b_eq = equality_rows(nd, topo, grads, n_cols, lam_col, force_col)
    A_nn, b_nn = contact_sign_rows(n_lam, lam_col, n_cols)
    blocks = [A_eq, A_nn]
    rhs = [b_eq, b_nn]
    cones = [clarabel.ZeroConeT(b_eq.size), clarabel.NonnegativeConeT(n_lam)]
    if with_yield:
        vertex_disc = replace(nd, volumes=np.repeat(nd.volumes, d + 1))
        A_soc, b_soc = yield_cone_rows(vertex_disc, 0, eta_col if has_eta else None, n_cols)
        blocks.append(A_soc)
        rhs.append(b_soc)
        cones += [clarabel.SecondOrderConeT(k)] * nv

    M = mass_matrix(d)
    q = np.zeros(n_cols)
    if limit:
        P = sp.csc_matrix((n_cols, n_cols))
        q[force_col] = -1.0
    else:
        pb = [sp.kron(sp.eye(n), sp.csr_matrix(np.triu(np.kron(M, m.compliance(d)))))]
        if has_eta:
            pb.append(sp.kron(sp.eye(n), sp.csr_matrix(np.triu(M) / m.hardening)))
        pb.append(sp.csr_matrix((n_lam, n_lam)))
        P = sp.block_diag(pb, format="csc")
        q[lam_col: lam_col + n_lam] = q_psi.ravel() / lam_w
    cols = dict(tau=slice(0, nv * k), eta=slice(eta_col, lam_col) if has_eta else None,
                lam=slice(lam_col, lam_col + n_lam), force=force_col)
    return Program(P, q, sp.vstack(blocks, format="csc"), np.concatenate(rhs), cones, b_eq.size, w, lam_w, cols)


# ----------------------------------------------------------------------------
# repair: exact projection onto the equality rows, lam >= 0 kept exactly
# ----------------------------------------------------------------------------

#: regularisation of the row-normalised Gram matrix A A^T (diagonal 1): redundant
#: traction rows make it singular; iterative refinement removes the regularisation's bias
GRAM_REGULARISATION = 1e-10


def _project_affine(A: sp.csc_matrix, b: np.ndarray, x: np.ndarray, max_refine: int = 10) -> tuple[np.ndarray, float]:
    """Minimum-norm correction of x onto ``A x = b`` (b in the range of A).

    Rows are normalised, ``K = A A^T + eps I`` is factored once and refined:
    ``x <- x + A^T K^{-1} (b - A x)``. Every correction lies in the range of A^T,
    so the limit is the minimum-norm correction even when rows are redundant
    (K singular without eps); each sweep shrinks the residual by
    ``eps / (sigma^2 + eps)`` for every nonzero singular value sigma of A.
    Returns ``(x, max |b - A x| / max_i sum_j |A_ij x_j|)`` after the last sweep.
    """
    from elastoplast.solvers.uzawa import factorize_metric

    A = sp.csr_matrix(A)
    norms = np.sqrt(np.asarray(A.multiply(A).sum(axis=1)).ravel())
    norms[norms == 0] = 1.0
    As = sp.diags(1.0 / norms) @ A
    bs = b / norms
    solve = factorize_metric((As @ As.T + GRAM_REGULARISATION * sp.eye(A.shape[0])).tocsc())
    x = x.copy()
    last = np.inf
    for _ in range(max_refine):
        r = bs - As @ x
        size = np.abs(r).max(initial=0.0)
        if size >= 0.5 * last:
            break
        x += As.T @ solve(r)
        last = size
    scale = max((abs(As) @ np.abs(x)).max(initial=0.0), np.finfo(float).tiny)
    return x, float(np.abs(bs - As @ x).max(initial=0.0) / scale)


def repair_static(prog: Program, x: np.ndarray, max_rounds: int = 10) -> tuple[np.ndarray, float, int]:
    """Project the solver's ``(tau_hat, lam_hat)`` exactly onto the equality rows,
    keeping ``lam >= 0`` exactly.

    Pressures that are not positive are fixed at 0 (their columns dropped) and the
    rest is projected; any pressure the correction drives negative joins them and
    the projection is repeated from there, so the answer has ``lam >= 0`` exactly
    and satisfies the rows to round-off. In limit mode F is held at the solver's
    value. Returns ``(x, relative residual, number of pressures fixed at zero)``.
    """
    x = x.copy()
    lam = np.zeros(x.size, dtype=bool)
    lam[prog.cols["lam"]] = True
    movable = np.zeros(x.size, dtype=bool)
    movable[prog.cols["tau"]] = True
    movable[prog.cols["lam"]] = True
    A_eq = prog.A[: prog.n_eq]
    zero = lam & (x <= 0.0)
    res = np.inf
    for _ in range(max_rounds):
        x[zero] = 0.0
        cols = movable & ~zero
        rhs = prog.b[: prog.n_eq] - A_eq[:, ~cols] @ x[~cols]
        x[cols], res = _project_affine(A_eq[:, cols], rhs, x[cols])
        neg = lam & (x < 0.0)
        if not neg.any():
            break
        zero |= neg
    return x, res, int(zero.sum())


# ----------------------------------------------------------------------------
# solving
# ----------------------------------------------------------------------------


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


def lower_bound_bytes(dim: int, n_elements: int) -> int:
    """Estimated peak memory of one lower-bound program on ``n_elements`` elements."""
    return int(LOWER_BOUND_BYTES_PER_ELEMENT[dim]) * int(n_elements)


def lower_bound_fits(dim: int, factor: float = SEQUENCE_MEMORY_FACTOR) -> int | None:
    """The most elements whose lower-bound programs (``factor`` times the estimate of
    one) fit in the memory available now (:func:`elastoplast.mesh.checks.available_memory`),
    or None where that is unknown."""
    from elastoplast.limits import available_memory

    limit, _ = available_memory()
    return None if limit is None else int(limit // (factor * LOWER_BOUND_BYTES_PER_ELEMENT[dim]))


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
                                 "benchmarks/bounds/solvers.md); coarsen the mesh, let 'elastoplast adapt' place the elements, "
                                 "or raise the limit with the lower bound's max_elements option")
    from elastoplast.limits import check_memory

    check_memory(int(factor * lower_bound_bytes(disc.dim, disc.n_elements)), "mesh",
                 f"the equilibrium-element lower bound with {solver} ({disc.n_elements:,} elements)",
                 "coarsen the mesh, or let 'elastoplast adapt' place the elements")


def _setup(disc: Discretization, options: LowerBoundOptions, force: float | None = None, limit: bool = False) -> _Setup:
    check_lower_bound_size(disc, options, limit)
    topo = facet_topology(disc.mesh, disc.problem.boundary)
    psi = psi_weights(disc, topo, options.psi_subdivisions)
    nd, units = nondimensionalize(disc if force is None else disc.with_force(force))
    _, grads = _element_geometry(disc.mesh)
    return _Setup(topo, psi, nd, units, grads * units.length)


def _clarabel(prog: Program, options: LowerBoundOptions, solver: str = "qdldl"):
    import clarabel

    conic = ConicOptions(ip_tol=options.ip_tol, max_iter=options.max_iter, verbose=options.verbose,
                         time_limit=options.time_limit)
    res = clarabel.DefaultSolver(prog.P, prog.q, prog.A, prog.b, prog.cones, clarabel_settings(conic, solver)).solve()
    raw = str(res.status).split(".")[-1]
    return _CLARABEL_STATUS.get(raw, Status.FAILED), raw, np.asarray(res.x), float(res.obj_val), int(res.iterations)


#: SCS's ``status_val`` (scs/include/glbopts.h) -> Status; 2 is "solved inaccurate", what
#: SCS returns at its iteration or time limit with a usable point
_SCS_STATUS = {1: Status.CONVERGED, 2: Status.MAX_ITERATIONS, -2: Status.INFEASIBLE, -7: Status.INFEASIBLE}


def _scs_cones(cones: list) -> dict:
    """Clarabel's cone list as SCS's cone dictionary (same row order: zero, nonnegative, SOC)."""
    z = sum(c.dim for c in cones if type(c).__name__ == "ZeroConeT")
    nn = sum(c.dim for c in cones if type(c).__name__ == "NonnegativeConeT")
    q = [c.dim for c in cones if type(c).__name__ == "SecondOrderConeT"]
    if len(cones) != (z > 0) + (nn > 0) + len(q):
        raise ValueError("cones other than zero, nonnegative and second-order")
    return {"z": z, "l": nn, "q": q}


def _scs(prog: Program, options: LowerBoundOptions):
    """SCS (O'Donoghue et al. 2016, 2021) on the same data ``(P, q, A, b, cones)``:
    SCS's and Clarabel's conventions agree (``A x + s = b``, ``s`` in the cones).
    Returns ``(status, raw status, x, objective, iterations)`` like :func:`_clarabel`.

    SCS is Douglas-Rachford splitting on the homogeneous self-dual embedding:
    each iteration solves one linear system with a matrix factored once (MKL PARDISO
    where installed, else QDLDL) and projects onto the cones (per element vertex, in
    closed form), with Anderson acceleration. Its residuals are of the size of
    ``scs_eps``; the repair makes its answer exactly admissible whatever they are.
    """
    import scs

    settings = dict(eps_abs=options.scs_eps, eps_rel=options.scs_eps, max_iters=options.scs_max_iter,
                    verbose=options.verbose)
    if options.time_limit is not None:
        settings["time_limit_secs"] = float(options.time_limit)
    data = {"P": sp.triu(prog.P, format="csc"), "A": sp.csc_matrix(prog.A), "b": prog.b, "c": prog.q}
    res = scs.SCS(data, _scs_cones(prog.cones), **settings).solve()
    info = res["info"]
    status = _SCS_STATUS.get(int(info["status_val"]), Status.FAILED)
    x = np.array(res["x"], dtype=float)
    # the slack of the rows -lam + s = 0 (s >= 0, contact_sign_rows) is lam projected onto
    # lam >= 0, with exact zeros where the contact is inactive: a better start for the
    # repair than x's own lam, which is off by SCS's residual (tiny values of either sign
    # would each cost the repair another round)
    lam = prog.cols["lam"]
    x[lam] = np.asarray(res["s"])[prog.n_eq: prog.n_eq + lam.stop - lam.start]
    return status, str(info["status"]), x, float(info["pobj"]), int(info["iter"])


@dataclass(frozen=True)
class _Answer:
    """A solver's answer to a lower-bound program, in its own words and in ours:
    ``infeasible`` (no admissible field) and ``unbounded`` (the objective has no
    bound below) are its certificates, whichever solver gave them."""

    solver: str
    status: Status
    raw: str
    x: np.ndarray
    objective: float
    iterations: int

    @property
    def infeasible(self) -> bool:
        return self.raw in ("PrimalInfeasible", "AlmostPrimalInfeasible", "infeasible", "infeasible_inaccurate")

    @property
    def unbounded(self) -> bool:
        return self.raw in ("DualInfeasible", "AlmostDualInfeasible", "unbounded", "unbounded_inaccurate")

    @property
    def label(self) -> str:
        return f"{'SCS' if self.solver == 'scs' else 'Clarabel'}: {self.raw}"


def _solve_program(disc: Discretization, prog: Program, options: LowerBoundOptions, solver: str) -> _Answer:
    """``prog`` solved by ``solver`` ("clarabel" or "scs")."""
    if solver == "scs":
        return _Answer(solver, *_scs(prog, options))
    return _Answer(solver, *_clarabel(prog, options, _kkt_solver(disc, options)))


def _field(s: _Setup, prog: Program, x: np.ndarray, force: float) -> StaticField:
    """User-unit field from program unknowns (eta left at zero)."""
    n, d, k = s.nd.n_elements, s.nd.dim, s.nd.k
    S = s.units.stress
    tau = x[prog.cols["tau"]].reshape(n, d + 1, k) / prog.weights[:, None, None] * S
    lam = (x[prog.cols["lam"]] / prog.lam_weights * S).reshape(-1, d)
    return StaticField(tau=tau, eta=np.zeros((n, d + 1)), contact_facets=s.topo.contact_facets, lam=lam,
                       force=float(force))


def _repaired_field(disc: Discretization, s: _Setup, prog: Program, x: np.ndarray) -> tuple[StaticField, float, int]:
    """:func:`repair_static`, then (H > 0) eta raised where the corrected tau needs it."""
    x, resid, zeroed = repair_static(prog, x)
    field = _field(s, prog, x, disc.force)
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
    options = LowerBoundOptions.of(options)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    s = _setup(disc, options)
    solver = lower_bound_solver(disc, options)
    m = disc.material
    nd = s.nd
    if m.hardening == 0:
        margin = _yield_margin(solver, options)
        nd = replace(nd, problem=replace(nd.problem, material=replace(nd.material, yield_stress=nd.material.yield_stress * (1 - margin))))
    q_nd = s.psi.q / (s.units.displacement * s.units.length ** (disc.dim - 1))
    timings["setup"] = time.perf_counter() - t0
    progs: dict[bool, Program] = {}

    @elastic_first
    def scaled(nd_: Discretization, with_yield: bool):
        t1 = time.perf_counter()
        prog = progs[with_yield] = lower_bound_program(nd_, s.topo, s.grads, q_nd, with_yield=with_yield)
        t2 = time.perf_counter()
        ans = _solve_program(disc, prog, options, solver)
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
    field, resid, zeroed = _repaired_field(disc, s, prog, x)
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
    options = LowerBoundOptions.of(options)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    m = disc.material
    area = facet_measure(disc.mesh.points[facet_topology(disc.mesh, disc.problem.boundary).contact_facets]).sum()
    s = _setup(disc, options, force=m.yield_stress * area, limit=True)  # stress unit = sigma_y
    prog = lower_bound_program(s.nd, s.topo, s.grads, np.zeros_like(s.psi.q), limit=True)
    timings["setup"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    solver = lower_bound_solver(disc, options, limit=True)
    ans = _solve_program(disc, prog, options, solver)
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
    field = _field(s, prog, x, F)
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
