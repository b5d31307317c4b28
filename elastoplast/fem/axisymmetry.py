"""Axisymmetric models in the meridian plane (docs/axisymmetry.md).

The body is the solid of revolution of a 2D mesh in ``x = r >= 0`` about the axis
``r = 0``. The discrete problem is plane strain's with two changes: each element
weighs ``w_T = 2 pi |T| r_T`` (``r_T`` its centroid's radius) instead of ``|T|``, and
the strain row that is zero in plane strain is the hoop strain, the mean nodal
radial displacement over ``r_T``. Nodes on the axis get ``u_r = 0``; a contact
node's force is that of its whole ring, and its pressure area the consistent ring
area ``2 pi int phi_i r ds``.
"""

from __future__ import annotations

import numpy as np

from elastoplast.errors import InputError
from elastoplast.mesh.base import Mesh


def ring_weights(mesh: Mesh, areas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(w, hoop)``: the element weights ``2 pi |T| r_T`` and ``1 / r_T`` (the hoop
    row's factor), from the triangles' areas ``|T|``."""
    r = mesh.points[mesh.cells, 0].mean(axis=1)
    return 2.0 * np.pi * areas * r, 1.0 / r


def axis_nodes(mesh: Mesh, tol: float) -> np.ndarray:
    """The nodes on the axis ``r = 0`` (within ``tol``)."""
    return np.flatnonzero(np.abs(mesh.points[:, 0]) <= tol)


def check_meridian_mesh(mesh: Mesh, clamped: tuple[str, ...], radial_fixed: tuple[str, ...], tol: float) -> None:
    """Refuse what an axisymmetric model cannot mean: a node at ``r < 0`` (the body
    lies on one side of the axis), an element with every vertex on the axis, and a
    clamp or a fixed radial displacement on a group lying on the axis (the axis is
    not a boundary: ``u_r = 0`` holds there by symmetry and is set without being
    named, and a clamp on a line of the revolved body holds nothing)."""
    x = mesh.points[:, 0]
    if np.any(x < -tol):
        i = int(np.argmin(x))
        raise InputError("mesh", f"{int(np.sum(x < -tol))} node(s) lie at r = x < 0 (e.g. node {i} at "
                                 f"{mesh.points[i].tolist()}): an axisymmetric model is the half-plane r >= 0 "
                                 "with its axis at x = 0")
    on_axis = np.abs(x) <= tol
    if np.any(np.all(on_axis[mesh.cells], axis=1)):
        raise InputError("mesh", "an element lies on the axis r = 0 (all its vertices): degenerate in revolution")
    for field, names in (("boundary.clamped", clamped), ("boundary.fix_component.x", radial_fixed)):
        for name in names:
            facets = np.asarray(mesh.groups[name])
            if facets.size and np.all(on_axis[facets]):
                raise InputError(field, f"group {name!r} lies on the axis r = 0: in an axisymmetric model the axis "
                                        "is not a boundary (u_r = 0 holds there by symmetry and is set without being "
                                        "named); remove it from the boundary conditions")


def ring_contact_area(mesh: Mesh, facets: np.ndarray) -> np.ndarray:
    """The consistent ring area ``2 pi int_Gamma phi_i r ds`` of each node over the
    segments ``facets (n, 2)`` (a segment of length h from r_a to r_b gives node a
    ``2 pi h (2 r_a + r_b) / 6``; an axis node gets ``pi h^2 / 3`` on a flat face)."""
    ra, rb = mesh.points[facets[:, 0], 0], mesh.points[facets[:, 1], 0]
    h = np.linalg.norm(mesh.points[facets[:, 1]] - mesh.points[facets[:, 0]], axis=1)
    area = np.zeros(mesh.n_nodes)
    np.add.at(area, facets[:, 0], 2.0 * np.pi * h * (2.0 * ra + rb) / 6.0)
    np.add.at(area, facets[:, 1], 2.0 * np.pi * h * (ra + 2.0 * rb) / 6.0)
    return area


def check_not_axisymmetric(problem, what: str) -> None:
    """Refuse ``what`` (a bound, the limit load, the adaptive loop) on an axisymmetric
    model, where it is not available: the plane and 3D constructions would certify the
    wrong body (the discrete energy evaluates the hoop strain at the centroid, below the
    field's true energy, so it is no upper bound), and P1 limit analysis locks there."""
    if getattr(problem, "axisymmetric", False):
        raise InputError("mesh.axisymmetric", f"{what} is not available for axisymmetric models yet (solve, paths, "
                                              "export and check are; docs/axisymmetry.md says why)")
