"""Statically admissible stress fields and what they certify (docs/bounds.md).

A field ``(tau, eta, lam)`` with linear stresses and hardening per element and facet
tractions ``lam`` on the contact zone gives the lower bound ``-J(tau, eta, lam) <= Pi*`` of
the continuous problem when it is statically and plastically admissible. This module
holds the field (:class:`StaticField`), its dual energy (:func:`dual_energy`, with
``int lam psi`` never under-estimated through :func:`psi_weights`), and the
solver-independent check of its admissibility (:func:`certify_static`).

In an axisymmetric model (docs/bounds.md, "Axisymmetric models") the field is written in
``tau = r sigma``: ``tau`` holds its vertex values (the hoop slot ``r_a sigma_thth``),
``hoop`` the hoop stress ``sigma_thth``, constant per element, and ``lam`` the traction
``r p`` of ``tau`` on Γ0 (p the pressure). Equilibrium is ``div tau = (sigma_thth, 0)``,
``tau n`` is continuous and ``tau = 0`` on the axis; the stress at a vertex off the axis
is ``sigma_a = tau_a / r_a``, every stress in the element is a convex combination of
these, and the energy is the vertex rule ``2 pi (|T| / 3) sum_a r_a (1/2 A sigma_a:sigma_a
+ eta_a^2 / 2H)``, an over-estimate of the exact integral (:func:`ring_vertex_stress`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastoplast.errors import InputError
from elastoplast.fem.assembly import STRAIN_ROWS, element_geometry, simplex_geometry
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import n_components, von_mises
from elastoplast.limits import blocks
from elastoplast.mesh.topology import FacetTopology, facet_measure, outward_facet_normals
from elastoplast.errors import expect

#: every residual of :func:`certify_static` must be at most this (relative to its stated scale)
CERTIFY_TOL = 1e-12


def traction_operator(v: np.ndarray) -> np.ndarray:
    """``N(v) (..., d, k)`` with ``N(v) tau = tau v`` for Mandel vectors ``tau``.

    It is the transpose of the Mandel symmetric gradient of ``u (x) v``
    (``STRAIN_ROWS``), since ``tau : sym(u (x) v) = (tau v) . u``. Hence also
    ``div tau = sum_a N(grad b_a) tau_a`` for a linear field with vertex values
    ``tau_a``. In plane strain the tau33 column is zero.
    """
    d = v.shape[-1]
    out = np.zeros(v.shape[:-1] + (d, n_components(d)))
    for c, terms in enumerate(STRAIN_ROWS[d]):
        for comp, der, w in terms:
            out[..., comp, c] += w * v[..., der]
    return out


def mass_matrix(dim: int) -> np.ndarray:
    """``int_S b_a b_b / |S| = (1 + delta_ab) / ((n+1)(n+2))`` on a ``dim``-simplex (n = dim)."""
    return (np.ones((dim + 1, dim + 1)) + np.eye(dim + 1)) / ((dim + 1) * (dim + 2))


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


@dataclass(frozen=True)
class StaticField:
    """A candidate stress field of the equilibrium element, in user units.

    ``tau (n_el, d+1, k)`` Mandel vertex values (in the order of ``mesh.cells``; in
    plane strain with tau33), ``eta (n_el, d+1)`` hardening stresses at the vertices,
    ``contact_facets (n_cf, d)`` node indices of the Γ0 facets (sorted per facet),
    ``lam (n_cf, d)`` contact pressure at their vertices (in that node order),
    ``force`` the F it balances. In an axisymmetric model ``tau`` is ``r sigma`` at the
    vertices, ``lam`` the traction ``r p`` of tau on Γ0 and ``hoop (n_el,)`` the hoop
    stress of each element (module docstring); None elsewhere.
    """

    tau: np.ndarray
    eta: np.ndarray
    contact_facets: np.ndarray
    lam: np.ndarray
    force: float
    hoop: np.ndarray | None = None


def vertex_radii(disc: Discretization) -> np.ndarray:
    """``r_a >= 0`` at the element vertices ``(n_el, 3)`` of an axisymmetric model (a
    vertex at ``r <= 0`` is on the axis)."""
    return np.maximum(disc.mesh.points[disc.mesh.cells, 0], 0.0)


def ring_vertex_stress(disc: Discretization, field: StaticField) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma, off_axis)``: the stresses ``sigma_a = (tau_a / r_a, sigma_thth)`` at the
    element vertices ``(n_el, 3, k)`` (zero on the axis) and the mask of the vertices off
    the axis, where they are defined."""
    r = vertex_radii(disc)
    off = r > 0
    sigma = np.where(off[..., None], np.asarray(field.tau, dtype=float) / np.where(off, r, 1.0)[..., None], 0.0)
    sigma[..., 2] = np.where(off, np.asarray(field.hoop, dtype=float)[:, None], 0.0)
    return sigma, off


def check_static_field(disc: Discretization, field: StaticField) -> None:
    """An InputError unless ``field`` is a :class:`StaticField` of ``disc``'s mesh."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    expect(field, StaticField, "field", "ep.solve_lower_bound(disc).field")
    if np.shape(field.tau) != (disc.n_elements, disc.dim + 1, disc.k):
        raise InputError("field", f"is the field of another mesh: tau has shape {np.shape(field.tau)}, this "
                                  f"discretisation's ({disc.n_elements}, {disc.dim + 1}, {disc.k})")
    ring = disc.problem.axisymmetric
    if ring and np.shape(field.hoop) != (disc.n_elements,):
        raise InputError("field.hoop", f"an axisymmetric field needs the hoop stress of each of the {disc.n_elements} "
                                       f"elements, got shape {np.shape(field.hoop)}")
    if not ring and field.hoop is not None:
        raise InputError("field.hoop", "is for axisymmetric models only")


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
    """The terms of :class:`LocalTerms`, integrated exactly with the P1 mass matrices (an
    axisymmetric model: :func:`ring_local_terms`)."""
    d, m = disc.dim, disc.material
    topo = disc.facet_topology if topo is None else topo
    psi = psi_weights(disc, topo) if psi is None else psi
    if disc.problem.axisymmetric:
        return ring_local_terms(disc, field, psi)
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


def ring_local_terms(disc: Discretization, field: StaticField, psi: PsiWeights) -> LocalTerms:
    """:class:`LocalTerms` of an axisymmetric field (module docstring): the energy by the
    vertex rule; ``element_stress = 2 pi |T| mean_a tau_a``, so that its product with the
    element strains of a P1 field (hoop row ``mean v_r / r_T``) is ``int_T sigma:eps(v) dV``;
    the facet terms those of the traction ``lam = r p`` times ``2 pi``."""
    m = disc.material
    area, _ = element_geometry(disc.mesh)
    sigma, off = ring_vertex_stress(disc, field)
    density = 0.5 * np.einsum("eai,ij,eaj->ea", sigma, m.compliance(2), sigma)
    if m.hardening > 0:
        density = density + 0.5 * np.asarray(field.eta, dtype=float) ** 2 / m.hardening
    r = vertex_radii(disc)
    tau = np.asarray(field.tau, dtype=float)
    measure = facet_measure(disc.mesh.points[field.contact_facets])
    return LocalTerms(
        element_energy=2.0 * np.pi * area / 3.0 * np.einsum("ea,ea->e", r, np.where(off, density, 0.0)),
        element_stress=2.0 * np.pi * area[:, None] * tau.mean(axis=1),
        facet_force=2.0 * np.pi * measure * field.lam.mean(axis=1),
        facet_psi_work=2.0 * np.pi * np.einsum("fa,fa->f", psi.q, field.lam),
    )


def dual_energy(disc: Discretization, field: StaticField, psi: PsiWeights | None = None) -> float:
    """``J = 1/2 int (A tau:tau + eta^2/H) + int lam psi_over``, integrated exactly
    (eta is ignored when H = 0; :func:`certify_static` requires it to vanish then)."""
    check_static_field(disc, field)
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

    Axisymmetric models (``tau = r sigma``, module docstring): ``equilibrium`` is that of
    ``div tau - (sigma_thth, 0)``; the scale uses ``F / (2 pi |Γ0|)`` and the force balance
    ``2 pi int_Γ0 lam``; ``yield_excess`` is checked on ``sigma_a = tau_a / r_a`` at the
    vertices off the axis; ``axis`` is ``max |tau_a| / s`` over the vertices on the axis
    (tau must vanish there), ``hoop`` is ``max |tau_a,thth - r_a sigma_thth| / s`` (tau's hoop
    slot is ``r sigma_thth``). Both are 0 elsewhere.

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
    axis: float = 0.0
    hoop: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in RESIDUALS}

    @property
    def worst(self) -> float:
        return float(np.max(list(self.as_dict().values())))  # a NaN residual stays NaN

    @property
    def failed(self) -> tuple[str, ...]:
        """Names of the residuals above the tolerance."""
        return tuple(k for k, v in self.as_dict().items() if not v <= self.tol)

    @property
    def passed(self) -> bool:
        return not self.failed


RESIDUALS = ("equilibrium", "traction_jump", "free_traction", "symmetry_traction", "contact_normal",
             "contact_tangential", "force_balance", "contact_sign", "yield_excess", "hardening", "axis", "hoop")


#: elements or facets per block of :func:`certify_static`'s batched operators
CERTIFY_BLOCK = 1 << 15


def _vmax(a: np.ndarray) -> float:
    return float(np.max(a, initial=0.0))


def certify_static(disc: Discretization, field: StaticField, tol: float = CERTIFY_TOL) -> StaticCertificate:
    """Check that ``field`` is statically and plastically admissible (docs/bounds.md).

    Uses only the mesh, the facet groups, the material and the field: facet normals
    and measures come from edge vectors (:func:`outward_facet_normals`), not from the
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
    check_static_field(disc, field)
    mesh, m = disc.mesh, disc.material
    topo = disc.facet_topology
    tau = np.asarray(field.tau, dtype=float)
    eta = np.asarray(field.eta, dtype=float)
    lam = np.asarray(field.lam, dtype=float)
    F = float(disc.force)  # the problem's load, not the one the field claims
    if not np.array_equal(np.asarray(field.contact_facets), topo.contact_facets):
        raise InputError("field.contact_facets", "do not match the contact facets of the problem")
    ring = disc.problem.axisymmetric
    measure_factor = 2.0 * np.pi if ring else 1.0  # the force of the traction lam: 2 pi int lam in revolution

    # equilibrium: div of the linear field from the barycentric gradients (by blocks of
    # elements: the operators of a whole split mesh at once are three times the field's size)
    div = np.empty((tau.shape[0], disc.dim))
    h = np.empty(tau.shape[0])
    for sl in blocks(tau.shape[0], CERTIFY_BLOCK):
        _, grads = simplex_geometry(mesh.points, mesh.cells[sl])
        div[sl] = np.einsum("eadk,eak->ed", traction_operator(grads), tau[sl])
        if ring:  # div tau = (sigma_thth, 0)
            div[sl, 0] -= np.asarray(field.hoop, dtype=float)[sl]
        h[sl] = 1.0 / np.linalg.norm(grads, axis=2).max(axis=1)

    contact_measure = facet_measure(mesh.points[topo.contact_facets])
    # Mandel vectors are orthonormal coordinates: their norm is the tensor's Frobenius norm
    # (squared by einsum: np.linalg.norm would square a copy of the whole field first)
    s = max(np.sqrt(_vmax(np.einsum("eak,eak->ea", tau, tau))), _vmax(lam),
            F / (measure_factor * contact_measure.sum()))

    def traction(elements, vertices, nodes):
        nrm = outward_facet_normals(mesh.points, mesh.cells, elements, nodes)
        t_vertex = tau[elements[:, None], vertices]  # (m, d, k)
        return np.einsum("mdk,mak->mad", traction_operator(nrm), t_vertex)

    ie, iv, inodes = topo.interior_elements, topo.interior_vertices, topo.interior_nodes
    jump = _vmax(np.array([_vmax(np.linalg.norm(traction(ie[sl, 0], iv[sl, 0], inodes[sl])
                                                + traction(ie[sl, 1], iv[sl, 1], inodes[sl]), axis=2))
                           for sl in blocks(ie.shape[0], CERTIFY_BLOCK)]))  # an array, so that a NaN block propagates
    tb = np.abs(traction(topo.boundary_elements, topo.boundary_vertices, topo.boundary_nodes))  # (n_bf, d vertices, d)
    zero = topo.zero_traction[:, None, :]
    free = ~topo.fixed.any(axis=1) & ~topo.contact
    sym = topo.fixed.any(axis=1) & ~topo.contact
    tb_signed = traction(topo.boundary_elements[topo.contact], topo.boundary_vertices[topo.contact],
                         topo.contact_facets)
    axis = hoop = 0.0
    if ring:
        sigma, off = ring_vertex_stress(disc, field)
        vm = np.where(off, von_mises(sigma.reshape(-1, disc.k)).reshape(eta.shape), -np.inf)
        axis = np.sqrt(_vmax(np.where(off, 0.0, np.einsum("eak,eak->ea", tau, tau)))) / s
        hoop = _vmax(np.abs(tau[..., 2] - vertex_radii(disc) * np.asarray(field.hoop, dtype=float)[:, None])) / s
    else:
        vm = von_mises(tau.reshape(-1, disc.k)).reshape(eta.shape)
    return StaticCertificate(
        equilibrium=_vmax(np.linalg.norm(div, axis=1) * h) / s,
        traction_jump=jump / s,
        free_traction=_vmax(np.where(zero, tb, 0.0)[free]) / s,
        symmetry_traction=_vmax(np.where(zero, tb, 0.0)[sym]) / s,
        contact_normal=_vmax(np.abs(tb_signed[:, :, -1] - lam)) / s,
        contact_tangential=_vmax(np.where(zero, tb, 0.0)[topo.contact]) / s,
        force_balance=abs(measure_factor * float(contact_measure @ lam.mean(axis=1)) - F) / F,
        contact_sign=_vmax(-lam) / s,
        yield_excess=_vmax(vm - m.yield_stress - eta) / m.yield_stress,
        hardening=0.0 if m.hardening > 0 else _vmax(np.abs(eta)) / m.yield_stress,
        scale=s,
        tol=tol,
        axis=axis,
        hoop=hoop,
    )
