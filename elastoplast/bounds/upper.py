"""Guaranteed bounds on the continuous problem: the upper bound and the energy bracket (docs/bounds.md).

Upper bound. Any ``(v, V)`` in the continuum set K (``v`` in H1 with its Dirichlet
conditions, ``v_d + psi - V >= 0`` on all of Γ0) gives ``Pi* <= Pi(v, V) = ∫ W(ε(v)) -
F V``, with the Hencky energy

    W(ε) = sup_{(τ, η) in D} τ:ε - 1/2 Aτ:τ - η²/(2H) = 1/2 Cε:ε - 1/2 ‖(Cε, 0) - R(ε)‖²

in the ``[.,.]`` metric (R the return mapping: the sup is attained at R(ε)). A P1
displacement is conforming and has a constant strain per element, so ``∫ W(ε(v))``
is exact element by element. Its non-penetration, though, holds at the nodes only:
:func:`penetration_bound` bounds the gap from below on every contact facet, and
``V`` is lowered by the largest penetration, which makes ``(v, V)`` admissible.

Facet rule (docs/bounds.md). On a contact facet ``g = I_h g + (psi - I_h psi)``;
``I_h g`` is at least the smallest nodal gap (round-off may leave that slightly
negative: it is kept), and if ``Hess psi <= k I`` on the facet then
``I_h psi - psi <= k r²/2`` with r the radius of the facet's smallest enclosing
ball: ``psi - k|x - c|²/2`` is concave, so it lies above its interpolant, and
``I_h |x - c|² - |x - c|² <= r²`` for c the ball's centre. Curvature bounds k:
sphere and cylinder ``R² / (R² - r_x²)^{3/2}`` (r_x the facet's largest distance
from the axis, the radial curvature, which exceeds the tangential one
``1/sqrt(R² - r_x²)``), paraboloid ``1/R``, flat 0. For an ``expression`` obstacle
nothing is known about its curvature: ψ is enclosed by interval arithmetic
(:mod:`elastoplast.problem.intervals`, outward rounding) on pieces of each facet, and on each
piece ``g >= min over the piece's corners of I_h(v_d - V) + inf_piece psi``;
facets whose bound is negative are cut into more pieces (up to
``EXPRESSION_PIECES``), which makes the bound first order in the piece size. If
ψ cannot be enclosed the bound is reported as not certified, with the reason.

Lower bound and the bracket: :mod:`elastoplast.bounds.lower` gives ``-J <= Pi*``;
:func:`combine` forms the bracket, the stress error bound and the local gap terms.
The U bracket (:func:`u_bracket`) uses the concavity of ``Pi*`` in F.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from elastoplast.certificate.kkt import energy_norm_sq, gaps
from elastoplast.fem.assembly import element_geometry
from elastoplast.fem.discretize import Discretization, check_hencky
from elastoplast.fem.material import Material, return_mapping
from elastoplast.certificate.kkt import real_number, shaped
from elastoplast.errors import InputError, expect
from elastoplast.options import check_array

#: most pieces per facet edge for an expression obstacle (1, 4, 16, ... up to this; 2D: that many
#: pieces per facet, 3D: its square)
EXPRESSION_PIECES = {2: 256, 3: 16}
#: boxes enclosed per call (bounds the memory of the expression enclosure)
BOXES_PER_CALL = 200_000


# ----------------------------------------------------------------------------
# the Hencky energy
# ----------------------------------------------------------------------------


def hencky_energy_density(material: Material, eps: np.ndarray) -> np.ndarray:
    """``W(ε) = 1/2 Cε:ε - 1/2 ‖(Cε, 0) - R(ε)‖²`` per row of Mandel strains ``eps (n, k)``.

    The squared distance is ``A(Cε - σ):(Cε - σ) + ξ²/H`` (ξ = 0 when H = 0); with the
    closed form of R it equals ``(3 mu + H) Δκ²``.
    """
    expect(material, Material, "material", "ep.make_material(E, nu, yield_stress, hardening)")
    eps = check_array("eps", eps)
    if eps.ndim != 2 or eps.shape[1] not in (4, 6):
        raise InputError("eps", f"expected Mandel strains (n, 4) in 2D or (n, 6) in 3D, got shape {eps.shape}")
    dim = 2 if eps.shape[-1] == 4 else 3
    sigma, xi, _ = return_mapping(material, eps)
    Ceps = eps @ material.stiffness(dim)
    r = Ceps - sigma
    dist2 = np.einsum("ei,ij,ej->e", r, material.compliance(dim), r)
    if material.hardening > 0:
        dist2 = dist2 + xi**2 / material.hardening
    return 0.5 * np.einsum("ei,ei->e", Ceps, eps) - 0.5 * dist2


def sub_lattice(k: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of a triangle cut into ``k x k`` similar sub-triangles: their
    barycentric coordinates ``(P, 3)`` and how many sub-triangles each is a vertex of."""
    ij = [(i, j) for i in range(k + 1) for j in range(k + 1 - i)]
    index = {p: n for n, p in enumerate(ij)}
    count = np.zeros(len(ij))
    for i, j in ij:
        if i + j <= k - 1:  # the sub-triangle pointing up from (i, j)
            for p in ((i, j), (i + 1, j), (i, j + 1)):
                count[index[p]] += 1
        if i + j <= k - 2:  # and the one pointing down
            for p in ((i + 1, j), (i, j + 1), (i + 1, j + 1)):
                count[index[p]] += 1
    bary = np.array([(i / k, j / k, (k - i - j) / k) for i, j in ij])
    return bary, count


def ring_element_energy(disc: Discretization, v: np.ndarray, eps: np.ndarray, subdivisions: int = 1) -> np.ndarray:
    """An upper bound of ``2 pi int_T W(eps(v)) r`` per element of an axisymmetric model
    (docs/bounds.md, "Axisymmetric models"), for nodal displacements ``v (n_nodes, 2)``.

    The in-plane strain ``eps_0`` of a P1 field is constant on T; the hoop strain
    ``v_r / r`` is a convex combination of the vertex ratios ``e_i = v_ri / r_i`` with
    weights ``lambda_i r_i / r``, whose integral against ``r`` is ``r_i |T| / 3``. W is
    convex, so ``int_T W r <= (|T| / 3) sum_i r_i W(eps_0 + e_i n_theta)`` (vertices on the
    axis drop out). With ``subdivisions = k`` the same rule is applied on each of the
    ``k x k`` sub-triangles of T (the field is P1 on each): tighter, still a bound.
    ``eps`` are the element strains of v (only the in-plane rows are read). A field with
    ``v_r != 0`` on the axis has infinite energy (it is not in H1 of the solid of revolution)."""
    bary, count = sub_lattice(subdivisions)
    cells = disc.mesh.cells
    r = np.maximum(disc.mesh.points[cells, 0], 0.0)  # (n, 3)
    vr = v[cells, 0]
    area, _ = element_geometry(disc.mesh)
    total = np.zeros(cells.shape[0])
    for lam, c in zip(bary, count):
        rj, vj = r @ lam, vr @ lam
        strain = np.array(eps, dtype=float)
        with np.errstate(all="ignore"):
            strain[:, 2] = np.where(rj > 0, vj / np.where(rj > 0, rj, 1.0), 0.0)
            # u_r != 0 on the axis: not in H1 of the body of revolution (infinite energy, not certified)
            total += np.where((rj > 0) | (vj == 0), c * rj * hencky_energy_density(disc.material, strain), np.inf)
    return 2.0 * np.pi * area / (3.0 * subdivisions**2) * total


def element_energy(disc: Discretization, v: np.ndarray, subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``(energy, eps)``: an upper bound of ``int_T W(eps(v))`` per element (exact for P1
    fields in plane strain and 3D, the vertex rule of :func:`ring_element_energy` in an
    axisymmetric model) and the element strains of the nodal field ``v``."""
    eps = disc.strain(disc.free_displacement(v))
    if not disc.problem.axisymmetric:
        return disc.volumes * hencky_energy_density(disc.material, eps), eps
    return ring_element_energy(disc, v, eps, subdivisions), eps


# ----------------------------------------------------------------------------
# non-penetration between the nodes
# ----------------------------------------------------------------------------


def contact_facets(disc: Discretization) -> np.ndarray:
    """The facets ``(n_cf, d)`` (node indices, sorted per facet) of the ``boundary.contact``
    groups: Γ0, as :attr:`~elastoplast.mesh.topology.FacetTopology.contact_facets` of
    ``disc.facet_topology``."""
    return disc.facet_topology.contact_facets


def enclosing_radius(X: np.ndarray) -> np.ndarray:
    """Radius of the smallest ball containing each simplex ``X (n, m+1, m)`` for m = 1, 2:
    half the length of a segment; for a triangle its circumradius ``abc / (4 area)``
    if no angle is obtuse, else half its longest edge."""
    if X.shape[1] == 2:
        return 0.5 * np.linalg.norm(X[:, 1] - X[:, 0], axis=1)
    e2 = np.stack([np.sum((X[:, (i + 1) % 3] - X[:, (i + 2) % 3]) ** 2, axis=1) for i in range(3)], axis=1)
    longest = e2.max(axis=1)
    obtuse = 2.0 * longest >= e2.sum(axis=1)  # a² >= b² + c² opposite the longest edge (right angles too)
    u, v = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    circum = np.sqrt(e2.prod(axis=1)) / np.maximum(4.0 * area, np.finfo(float).tiny)
    return np.where(obtuse, 0.5 * np.sqrt(longest), circum)


def curvature_bound(disc: Discretization, X: np.ndarray) -> np.ndarray:
    """``k >= lambda_max(Hess psi)`` on each facet with in-plane vertices ``X (n, d, d-1)``
    (known shapes only; module docstring)."""
    ob = disc.problem.obstacle
    if ob.shape == "flat":
        return np.zeros(X.shape[0])
    if ob.shape == "paraboloid":
        return np.full(X.shape[0], 1.0 / ob.radius)
    if ob.shape in ("sphere", "cylinder"):
        R = ob.radius
        rx = np.linalg.norm(X - np.asarray(ob.center), axis=2).max(axis=1)
        # Obstacle.psi refused any node at distance >= R, so rx < R on every facet
        return R**2 / (R**2 - rx**2) ** 1.5
    raise ValueError(f"no curvature bound for the {ob.shape!r} obstacle")


@dataclass(frozen=True)
class Penetration:
    """Lower bounds of the gap ``v_d + psi - V`` on every contact facet.

    ``facets (n_cf, d)`` are those of :func:`contact_facets`, ``facet_gap`` a lower
    bound of the gap on each (negative: possible penetration), ``max_penetration =
    max(0, -min facet_gap)``; ``certified`` says whether every facet bound is
    proved, ``method`` how they were obtained.
    """

    max_penetration: float
    facet_gap: np.ndarray
    facets: np.ndarray
    certified: bool
    method: str

    def __iter__(self):
        """``max_penetration, facet_gap = penetration_bound(...)`` unpacks the two bounds."""
        return iter((self.max_penetration, self.facet_gap))


def _expression_gap(disc: Discretization, X: np.ndarray, base: np.ndarray) -> tuple[np.ndarray | None, str]:
    """Facet lower bounds ``min_pieces [min_corners I_h(v_d - V) + inf_piece psi]`` for an
    expression obstacle; ``base (n_cf, d)`` are the nodal values ``v_d - V``."""
    from elastoplast.problem.intervals import Unbounded, enclose, facet_pieces

    d = disc.dim
    ob = disc.problem.obstacle
    size = np.abs(X.max(axis=1) - X.min(axis=1)).max(axis=1)
    lower = np.full(X.shape[0], -np.inf)
    todo = np.arange(X.shape[0])
    m = 1
    while todo.size:
        bary = facet_pieces(d, m)  # (P, d corners, d vertices)
        for chunk in np.array_split(todo, max(1, todo.size * bary.shape[0] // BOXES_PER_CALL)):
            corners = np.einsum("pva,fac->fpvc", bary, X[chunk])
            pad = (1e-12 * size[chunk] + np.finfo(float).tiny)[:, None, None]
            lo, hi = corners.min(axis=2) - pad, corners.max(axis=2) + pad
            try:
                inf_psi, _ = enclose(ob.expression, d, lo.reshape(-1, d - 1), hi.reshape(-1, d - 1))
            except Unbounded as exc:
                return None, str(exc)
            linear = np.einsum("pva,fa->fpv", bary, base[chunk]).min(axis=2)  # exact for linear I_h
            lower[chunk] = np.maximum(lower[chunk], (linear + inf_psi.reshape(linear.shape)).min(axis=1))
        m *= 4
        if m > EXPRESSION_PIECES[d]:
            break
        todo = todo[lower[todo] < 0]
    return lower, ""


def penetration_bound(disc: Discretization, u: np.ndarray, U: float) -> Penetration:
    """How far ``(u, U)`` may penetrate the obstacle between the nodes (module docstring).

    ``u``: nodal displacements ``(n_nodes, d)`` or the free-dof vector.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    U = real_number("U", U)
    u = _nodal(disc, u)
    d = disc.dim
    facets = contact_facets(disc)
    X = disc.mesh.points[facets][:, :, :-1]
    ob = disc.problem.obstacle
    if ob.shape == "expression":
        base = u[facets, d - 1] - U
        lower, reason = _expression_gap(disc, X, base)
        if lower is None:
            g = gaps(disc, disc.free_displacement(u), U)
            position = np.full(disc.mesh.n_nodes, -1)
            position[disc.contact_nodes] = np.arange(disc.n_contact)
            lower = g[position[facets]].min(axis=1)
            certified, method = False, f"nodal gaps only (psi could not be enclosed: {reason})"
        else:
            certified, method = True, "interval enclosure of psi on pieces of each facet"
    else:
        psi = ob.psi(X.reshape(-1, d - 1), field="obstacle").reshape(-1, d)
        nodal = u[facets, d - 1] + psi - U
        k = curvature_bound(disc, X)
        lower = nodal.min(axis=1) - 0.5 * np.maximum(k, 0.0) * enclosing_radius(X) ** 2
        certified, method = True, f"smallest nodal gap minus k r^2/2 ({ob.shape})"
    return Penetration(max_penetration=float(max(0.0, -lower.min(initial=0.0))), facet_gap=lower, facets=facets,
                       certified=certified, method=method)


def _nodal(disc: Discretization, u: np.ndarray, field: str = "u") -> np.ndarray:
    u = check_array(field, u)
    if u.ndim == 1 and u.size == disc.n_free:
        return disc.full_displacement(u)
    return shaped(u, (disc.mesh.n_nodes, disc.dim), field)


# ----------------------------------------------------------------------------
# the upper bound
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class UpperBound:
    """``Pi* <= Pi = ∫ W(ε(v)) - F V`` at an admissible ``(v, V)`` (user units).

    ``U`` and ``penetration`` are the candidate's own rigid displacement and the
    bound on how far it penetrates between the nodes; ``v`` is the candidate with
    its contact nodes lifted by up to ``lift`` and ``V = U - shift`` (see
    :func:`upper_bound`). ``element_energy`` is ``|T| W(ε_T(v))``, ``strain`` the
    element strains of v, ``u`` its nodal values (at the mesh's ``points``);
    ``stress_norm`` is ``sqrt([R(ε(v)), R(ε(v))])``, the energy norm of the
    stresses v implies; ``facet_gap`` the lower bounds of the gap of ``(v, V)`` on
    the contact facets (all ``>= 0``). ``certified`` only when every step is a
    proof (``message`` says which was not).
    """

    Pi: float
    V: float
    U: float
    penetration: float
    shift: float
    lift: float
    element_energy: np.ndarray = field(repr=False)
    strain: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    points: np.ndarray = field(repr=False)
    stress_norm: float
    facet_gap: np.ndarray = field(repr=False)
    certified: bool
    message: str


#: shifts of V tried by :func:`upper_bound` (quantiles of the nodal lifts)
N_SHIFTS = 17


def node_lifts(disc: Discretization, pen: Penetration) -> np.ndarray:
    """``p_i`` = the largest penetration bound over the contact facets at node i
    (zero elsewhere): raising ``v_d`` at every node of a facet by at least its
    penetration raises its gap bound to ``>= 0``, since on a facet both rules
    (``min nodal gap - k r²/2`` and the piecewise enclosure) grow by the smallest
    rise of its nodes."""
    p = np.zeros(disc.mesh.n_nodes)
    np.maximum.at(p, pen.facets.ravel(), np.repeat(np.maximum(-pen.facet_gap, 0.0), pen.facets.shape[1]))
    return p


#: the sub-triangles per element edge of the axisymmetric vertex rule by default
#: (:func:`ring_element_energy`): its over-estimate falls as ``1 / k^2`` (measured on the
#: sphere of tests/test_axisymmetric.py, 16 x 16 graded divisions: Pi = -10.8810, -10.9690,
#: -10.9914, -10.9971 for k = 1, 2, 4, 8), at ``(k + 1)(k + 2) / 2`` return mappings per element
RING_SUBDIVISIONS = 8


def upper_bound(disc: Discretization, candidate, correction: str = "best", subdivisions: int | None = None) -> UpperBound:
    """The upper bound of a P1 candidate: a :class:`~elastoplast.certificate.solution.Solution`
    or a pair ``(u, U)`` (``u`` nodal ``(n_nodes, d)`` or on the free dofs).

    The candidate is made admissible in one of two ways, or a mix: lower V by a
    shift s (costs ``F s``) and lift ``v_d`` at each contact node by
    ``max(0, p_i - s)`` (:func:`node_lifts`; costs about ``Σ λ_i max(0, p_i - s)``
    to first order, much less than ``F max p`` when the largest penetrations sit
    where the contact force is small, as at the edge of a contact zone on a graded
    mesh). ``correction``: ``"shift"`` (s = max p, docs/bounds.md's rule),
    ``"lift"`` (s = 0) or ``"best"`` (the smallest Pi over s in 0, the
    quantiles of the lifts and max p). Whatever s, Pi is evaluated exactly at the
    corrected ``(v, V)``, whose gap bounds are recomputed (any round-off
    penetration left is taken off V): nothing but the candidate's displacements
    enter, so any candidate gives a valid bound. In an axisymmetric model the energy
    is the vertex rule of :func:`ring_element_energy` on ``subdivisions x
    subdivisions`` sub-triangles of each element (None: :data:`RING_SUBDIVISIONS`; ignored
    elsewhere, where the energy is exact).
    """
    from elastoplast.certificate.kkt import real_number, shaped
    from elastoplast.certificate.solution import Solution, check_solution
    from elastoplast.errors import InputError, expect
    from elastoplast.options import check_array

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_hencky(disc, "the upper bound")
    subdivisions = RING_SUBDIVISIONS if subdivisions is None else subdivisions
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or not 1 <= subdivisions <= 64:
        raise InputError("subdivisions", f"must be an integer in [1, 64], got {subdivisions!r}")
    if isinstance(candidate, Solution):
        check_solution(disc, candidate, "candidate", reads=("u",))
        real_number("candidate.U", candidate.U)
    elif isinstance(candidate, (tuple, list)) and len(candidate) == 2:
        u_given = check_array("candidate.u", candidate[0])
        if not (u_given.ndim == 1 and u_given.size == disc.n_free):  # else nodal, in any layout
            shaped(u_given, (disc.mesh.n_nodes, disc.dim), "candidate.u")
        real_number("candidate.U", candidate[1])
    else:
        raise InputError("candidate", f"expected a Solution or a pair (u, U), u nodal ({disc.mesh.n_nodes}, "
                                      f"{disc.dim}) or on the {disc.n_free} free dofs; got {type(candidate).__name__}")
    if correction not in ("best", "shift", "lift"):
        from elastoplast.errors import InputError

        raise InputError("correction", f"must be 'best', 'shift' or 'lift', got {correction!r}")
    u, U = (candidate.u, candidate.U) if hasattr(candidate, "kkt") else candidate
    u = _nodal(disc, u)
    U = float(U)
    m, d, F = disc.material, disc.dim, disc.force
    pen = penetration_bound(disc, u, U)
    p = node_lifts(disc, pen)
    if correction == "shift":
        shifts = np.array([pen.max_penetration])
    elif correction == "lift":
        shifts = np.zeros(1)
    else:
        shifts = np.unique(np.concatenate([[0.0], np.quantile(p[p > 0], np.linspace(0, 1, N_SHIFTS))])) \
            if np.any(p > 0) else np.zeros(1)

    def lifted(shift: float) -> tuple[np.ndarray, np.ndarray, float]:
        v = u.copy()
        v[:, d - 1] += np.maximum(p - shift, 0.0)
        with np.errstate(all="ignore"):  # energies out of range: not finite, and not certified below
            energy, _ = element_energy(disc, v, int(subdivisions))
            return v, energy, float(energy.sum() - F * (U - shift))

    s = min(shifts, key=lambda t: lifted(t)[2])
    v, energy, _ = lifted(s)
    after = penetration_bound(disc, v, U - s)
    V = U - s - after.max_penetration
    eps = disc.strain(disc.free_displacement(v))
    sigma, xi, _ = return_mapping(m, eps)
    lift = float(np.maximum(p - s, 0.0).max(initial=0.0))
    notes = [f"gap between nodes: {pen.method}", f"largest penetration {pen.max_penetration:.3e}",
             f"V lowered by {U - V:.3e}, contact nodes lifted by up to {lift:.3e} ({correction})"]
    with np.errstate(all="ignore"):  # an energy out of range is not finite: not certified, said below
        Pi = float(energy.sum() - F * V)
    finite = bool(np.all(np.isfinite(v)) and np.isfinite(V) and np.isfinite(Pi))
    if not finite:
        notes.append("the candidate or its energy is not finite")
    return UpperBound(
        Pi=Pi,
        V=float(V),
        U=U,
        penetration=pen.max_penetration,
        shift=float(U - V),
        lift=lift,
        element_energy=energy,
        strain=eps,
        u=v,
        points=disc.mesh.points,
        stress_norm=float(np.sqrt(energy_norm_sq(disc, sigma, xi))),
        facet_gap=after.facet_gap + ((U - s) - V),  # V as rounded
        certified=bool(pen.certified and after.certified and finite),
        message="; ".join(notes),
    )


# ----------------------------------------------------------------------------
# the bracket
# ----------------------------------------------------------------------------


def conservative_discretization(disc: Discretization) -> Discretization:
    """``disc`` with ψ lowered at every contact node by the largest interpolation
    allowance ``c_f`` of its facets (``k r²/2``, or what the interval enclosure
    gives for an expression: the facet rule applied to zero nodal gaps).

    A P1 solution of this problem has nodal gaps ``>= c_f`` against the true ψ on
    every facet, so it needs no correction: the discrete solver places it where
    a shift or lift (:func:`upper_bound`) would only push it afterwards.
    Measured on the 2D cylinder (80 x 40 divisions): Pi = -104.311 from this
    solution against -104.120 (best correction) and -103.910 (shift) from the
    solution of the original problem, whose own discrete value is -104.671.
    """
    d = disc.dim
    u = np.zeros((disc.mesh.n_nodes, d))
    u[disc.contact_nodes, d - 1] = -disc.psi  # zero nodal gaps with U = 0
    allowance = node_lifts(disc, penetration_bound(disc, u, 0.0))
    return replace(disc, psi=disc.psi - allowance[disc.contact_nodes])


def smallest_upper_bound(disc: Discretization, solution, conservative_solution=None) -> UpperBound:
    """The smallest of the upper bounds of ``solution``, of ``conservative_solution``
    (a solution of :func:`conservative_discretization`, when given) and of the body at
    rest ``(v, V) = (0, 0)``, corrected like any candidate, so admissible whatever ψ.
    Each is a bound; a certified one ranks before one that is not, whatever their
    values. The body at rest wins only when the P1 candidates are poor (a coarse mesh
    or a solve cut short), whose energy can exceed the unloaded body's."""
    candidates = [upper_bound(disc, solution)]
    if conservative_solution is not None:
        other = upper_bound(disc, conservative_solution)
        candidates.append(replace(other, message=f"{other.message}; from the solution with the conservative obstacle"))
    rest = upper_bound(disc, (np.zeros((disc.mesh.n_nodes, disc.dim)), 0.0))
    candidates.append(replace(rest, message=f"{rest.message}; the body at rest (no P1 candidate did better)"))
    return min(candidates, key=lambda c: (not c.certified, c.Pi))


# ----------------------------------------------------------------------------
# the U bracket
# ----------------------------------------------------------------------------


# ----------------------------------------------------------------------------
# everything the bounds command reports
# ----------------------------------------------------------------------------


