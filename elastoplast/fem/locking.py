"""Perfect plasticity (H = 0), and hardening too small for the load, on meshes that lock: P1 elements whose
divergence-free fields are too few.

A mesh locks when the incompressible plastic flow it must carry has no P1 representative; the solvers refuse
H = 0 there (:func:`check_perfect_plasticity`), and a hardening that cannot carry the force within small strains
(:func:`check_hardening_carries_load`): either way the continuum would flow where the locking elements do not,
so the answer is no reference. :data:`SMALL_STRAIN_LIMIT` is the strain beyond which no answer is called
converged, on any mesh (:mod:`elastoplast.certificate.solution`)."""

from __future__ import annotations

import numpy as np

from elastoplast.errors import InputError
from elastoplast.mesh.topology import boundary_facets, element_edges, unique_rows

CROSSED_TOLERANCE = 1e-6  # |sin| of the angle between the two halves of a crossing line

#: the largest strain |eps| (the Frobenius norm, element by element) of an answer of the small-strain model:
#: beyond it the model's own error, of the order of the strain, is no longer small (the shipped problems
#: reach 0.013, the test suite's 0.025); an answer above it is not called converged
SMALL_STRAIN_LIMIT = 0.1

#: the largest mean contact pressure, in flow stresses, a body that flows plastically is taken to carry:
#: twice the hardness of a rigid-plastic half-space (about 3: Prandtl's flat punch (2 + pi)/sqrt(3) = 2.97
#: in plane strain; Tabor's 2.8 to 3 in 3D), the factor 2 for finite, clamped blocks (measured: the
#: kinematic bounds of the shipped blocks 2.8 in 2D and 3.4 to 3.7 on coarse 3D meshes)
BEARING_FACTOR = 6.0


def crossed_centres(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Nodes that are the centre of a crossed quadrilateral (boolean per node).

    A criss-cross centre is an interior node of exactly four triangles whose four
    edges lie on two straight lines (its quadrilateral's diagonals): around such a
    "singular vertex" the divergences of P1 fields on the four triangles satisfy one
    linear relation, which is what keeps the crossed pattern free of locking under
    plastic incompressibility. Boundary nodes are never centres (a half-crossed
    quadrilateral on the boundary has no such relation).
    """
    n = points.shape[0]
    degree = np.bincount(cells.ravel(), minlength=n)
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[boundary_facets(cells, n).ravel()] = True
    candidate = (degree == 4) & ~on_boundary
    if not np.any(candidate):
        return candidate
    undirected, _ = element_edges(cells, n)
    edges = np.concatenate([undirected, undirected[:, ::-1]], axis=0)  # each edge from either end
    edges = edges[candidate[edges[:, 0]]]
    edges, _, _ = unique_rows(edges, n)  # sorted by centre, then neighbour
    per_centre = np.bincount(edges[:, 0], minlength=n)
    candidate &= per_centre == 4
    edges = edges[candidate[edges[:, 0]]]
    centres = edges[::4, 0]
    v = (points[edges[:, 1]] - points[edges[:, 0]]).reshape(-1, 4, 2)
    angle = np.arctan2(v[..., 1], v[..., 0])
    v = v[np.arange(len(v))[:, None], np.argsort(angle, axis=1)]  # counter-clockwise
    length = np.linalg.norm(v, axis=2)
    ok = np.ones(len(centres), dtype=bool)
    for a, b in ((0, 2), (1, 3)):  # opposite neighbours: collinear through the centre, on either side
        cross = v[:, a, 0] * v[:, b, 1] - v[:, a, 1] * v[:, b, 0]
        dot = np.einsum("ij,ij->i", v[:, a], v[:, b])
        ok &= (np.abs(cross) <= CROSSED_TOLERANCE * length[:, a] * length[:, b]) & (dot < 0)
    result = np.zeros(n, dtype=bool)
    result[centres[ok]] = True
    return result


def locking_elements(points: np.ndarray, cells: np.ndarray, axisymmetric: bool = False) -> np.ndarray:
    """Elements that lock under plastic incompressibility (boolean per element): in
    2D the triangles with no criss-cross centre among their vertices, in 3D every
    tetrahedron (P1 tetrahedra lock on practically any mesh), in an axisymmetric model
    every triangle (with the hoop row no nonzero P1 field is incompressible element by
    element, crossed or not)."""
    if points.shape[1] == 3 or axisymmetric:
        return np.ones(cells.shape[0], dtype=bool)
    return ~np.any(crossed_centres(points, cells)[cells], axis=1)


def is_axisymmetric(disc) -> bool:
    """Whether ``disc`` (a Discretization or a Problem) is an axisymmetric model."""
    return bool(getattr(getattr(disc, "problem", disc), "axisymmetric", False))


def check_perfect_plasticity(disc) -> None:
    """Refuse ``hardening = 0`` on a mesh whose P1 elements lock.

    With perfect plasticity the plastic flow is incompressible. P1 triangles meet that
    constraint only on crossed meshes (four triangles per quadrilateral meeting at the
    intersection of its diagonals); two triangles per square and unstructured
    triangulations lock, and P1 tetrahedra lock on practically any mesh. On a locking
    mesh the discrete limit load lies far above the continuum's (measured: a flat punch
    solved at 3 x Prandtl's load in 2D; a 3D block "converged" to a U of metres on a
    block of millimetres), so the answer is no reference. ``disc`` is a
    :class:`Discretization` or a :class:`Problem` (anything with ``material`` and
    ``mesh``). Meant for the solve path only: the limit-load and bound programs do not
    use these elements for the velocity/stress fields that would lock.
    """
    if disc.material.hardening > 0:
        return
    mesh = disc.mesh
    axisymmetric = is_axisymmetric(disc)
    bad = locking_elements(mesh.points, mesh.cells, axisymmetric)
    if not np.any(bad):
        return
    if axisymmetric:
        why = ("axisymmetric P1 triangles lock under plastically incompressible flow on every mesh, crossed or not "
               "(the hoop strain leaves no incompressible P1 field)")
        instead = "use hardening > 0"
    elif mesh.dim == 3:
        why = "P1 tetrahedra lock under plastically incompressible flow on practically any mesh"
        instead = "use hardening > 0, or `elastoplast limit` for the limit load"
    else:
        why = (f"{int(bad.sum())} of {bad.size} triangles are not in a crossed quadrilateral (four triangles meeting "
               "at the intersection of its diagonals), and such P1 triangles lock under plastically incompressible "
               "flow")
        instead = ("use hardening > 0, or a crossed mesh (pattern = \"crossed\"), or `elastoplast limit` for the "
                   "limit load")
    raise InputError("material.hardening",
                     f"hardening = 0 (perfect plasticity) on this mesh gives no reference answer: {why}, so the "
                     f"discrete limit load lies far above the true one; {instead}")


def overload(disc) -> tuple[float, float] | None:
    """``(mean contact pressure F / |Gamma_0|, flow stress sigma_y + H SMALL_STRAIN_LIMIT)`` when
    the pressure exceeds :data:`BEARING_FACTOR` flow stresses (the force is then far above
    what the body carries within small strains), else None."""
    m = disc.material
    area = float(disc.contact_area.sum())
    if area <= 0:
        return None
    pressure = disc.force / area
    flow = m.yield_stress + m.hardening * SMALL_STRAIN_LIMIT
    return (pressure, flow) if pressure > BEARING_FACTOR * flow else None


def check_hardening_carries_load(disc) -> None:
    """Refuse, on a mesh whose P1 elements lock, a force its hardening cannot carry within
    small strains: the neighbourhood of H = 0 that :func:`check_perfect_plasticity` refuses.

    Within the strain :data:`SMALL_STRAIN_LIMIT` the hardening raises the flow stress to at
    most ``sigma_y + H * SMALL_STRAIN_LIMIT``, and a body that flows carries a mean contact
    pressure of at most :data:`BEARING_FACTOR` flow stresses. The mean pressure over the
    declared contact zone, ``F / |Gamma_0|``, is at most the true one (the contact is no
    larger than the zone); above ``BEARING_FACTOR (sigma_y + H SMALL_STRAIN_LIMIT)`` the
    continuum's answer leaves small strains, while the locking elements carry the force
    with small ones, so the answer is no reference. Meshes that do not lock are left to
    the strain of their answer, which is then faithful. ``disc`` is a
    :class:`Discretization` (its contact areas are needed).

    This is an estimate that refuses only what lies far beyond the limit load. Between the
    limit load and it, an answer on a locking mesh with little hardening is still too stiff
    (measured, a flat punch at 1.2 times Prandtl's load on 20 x 10 squares: U = 0.027 with
    two triangles per square for every H from E/1000 down to 1e-7 E, against 0.26 and 2400
    on the crossed mesh); ``elastoplast bounds`` measures how far it is from the continuum.
    """
    m = disc.material
    excess = overload(disc)
    if m.hardening <= 0 or excess is None:  # H = 0 is check_perfect_plasticity's
        return
    pressure, flow = excess
    mesh = disc.mesh
    axisymmetric = is_axisymmetric(disc)
    if not np.any(locking_elements(mesh.points, mesh.cells, axisymmetric)):
        return
    needed = (pressure / BEARING_FACTOR - m.yield_stress) / SMALL_STRAIN_LIMIT
    where = ("axisymmetric P1 triangles" if axisymmetric else "P1 tetrahedra" if mesh.dim == 3
             else "triangles not in a crossed quadrilateral")
    instead = "or a smaller force" + ("" if mesh.dim == 3 or axisymmetric else ", or a crossed mesh (pattern = \"crossed\")")
    raise InputError("material.hardening",
                     f"hardening = {m.hardening:g} cannot carry force = {disc.force:g} within small strains on a mesh "
                     f"that locks ({where}): the mean pressure over the contact zone, {pressure:.3g}, is "
                     f"{pressure / flow:.3g} flow stresses sigma_y + {SMALL_STRAIN_LIMIT:g} H = {flow:.3g} (the most "
                     f"hardening gives at a strain of {SMALL_STRAIN_LIMIT:g}), more than the {BEARING_FACTOR:g} a "
                     "flowing body carries, so the continuum's answer leaves small strains where the locking "
                     f"elements' does not: no reference; use a hardening of at least {needed:.3g}, {instead}")
