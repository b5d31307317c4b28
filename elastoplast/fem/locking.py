"""Perfect plasticity (H = 0) on meshes that lock: P1 elements whose divergence-free fields are too few.

A mesh locks when the incompressible plastic flow it must carry has no P1 representative; the solvers refuse
H = 0 there (:func:`check_perfect_plasticity`)."""

from __future__ import annotations

import numpy as np

from elastoplast.errors import InputError
from elastoplast.mesh.topology import boundary_facets, unique_rows

CROSSED_TOLERANCE = 1e-6  # |sin| of the angle between the two halves of a crossing line


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
    edges = np.concatenate([cells[:, [a, b]] for a in range(3) for b in range(3) if a != b], axis=0)
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


def locking_elements(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Elements that lock under plastic incompressibility (boolean per element): in
    2D the triangles with no criss-cross centre among their vertices, in 3D every
    tetrahedron (P1 tetrahedra lock on practically any mesh)."""
    if points.shape[1] == 3:
        return np.ones(cells.shape[0], dtype=bool)
    return ~np.any(crossed_centres(points, cells)[cells], axis=1)


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
    bad = locking_elements(mesh.points, mesh.cells)
    if not np.any(bad):
        return
    if mesh.dim == 3:
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
