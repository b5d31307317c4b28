"""Checks that a mesh file holds one connected, conforming body with valid facet groups.

Every check raises :class:`InputError` naming the field the user wrote (``mesh.file``,
``mesh.divisions``, ``material.hardening``, ...) with a one-line message, or warns
(``warnings.warn``) where the input is legal but has been repaired or is questionable.
Everything here works on whole arrays (no loop over elements or nodes) and allocates
nothing before the memory checks have passed.
"""

from __future__ import annotations

import warnings
from typing import Mapping

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from elastoplast.errors import InputError, short_repr
from elastoplast.mesh.topology import element_facets, local_edges, locate_rows, outward_facet_normals, unique_rows

# ----------------------------------------------------------------------------
# mesh topology (files): one connected, conforming body
# ----------------------------------------------------------------------------

MERGE_TOLERANCE = 1e-10  # coincident nodes: closer than this times the mesh extent


def merge_coincident_nodes(points: np.ndarray, used: np.ndarray, field: str) -> tuple[np.ndarray, int]:
    """Map each node to one representative of the nodes at its position.

    Only the ``used`` nodes are compared (gmsh keeps geometry points that no element
    uses). Nodes closer than ``MERGE_TOLERANCE`` times the extent of the used nodes
    are one node: separate copies of the nodes on an interface (two volumes meshed
    without sharing their surface) leave the parts unconnected, which would be solved
    as separate bodies. Returns ``(target, n_merged)``, ``target[i]`` the smallest
    index at node i's position; warns, naming ``field``, when any are merged.
    """
    from scipy.spatial import cKDTree

    target = np.arange(points.shape[0])
    if used.size < 2:
        return target, 0
    P = points[used]
    extent = float(np.max(P.max(axis=0) - P.min(axis=0)))
    tol = MERGE_TOLERANCE * extent
    pairs = cKDTree(P).query_pairs(tol, output_type="ndarray") if extent > 0 else np.zeros((0, 2), dtype=np.int64)
    if pairs.size == 0 and extent > 0:
        return target, 0
    if extent == 0:  # every node at one point
        pairs = np.stack([np.zeros(used.size - 1, dtype=np.int64), np.arange(1, used.size)], axis=1)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(used.size, used.size))
    n_groups, labels = connected_components(graph, directed=False)
    first = np.full(n_groups, used.size, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(used.size))
    target[used] = used[first[labels]]
    n_merged = used.size - n_groups
    warnings.warn(f"{field}: merged {n_merged} coincident node(s) into others (nodes closer than "
                  f"{MERGE_TOLERANCE:g} x the mesh extent {extent:.4g} are one node)", stacklevel=3)
    return target, n_merged


def check_conforming(points: np.ndarray, cells: np.ndarray, field: str) -> tuple[np.ndarray, np.ndarray]:
    """Refuse a mesh that is not one connected, conforming body; return the unique
    facets and how many elements share each (1 on the boundary, 2 inside).

    In a conforming simplicial mesh of one body, (1) no element is repeated and none
    has two vertices at one node, (2) every facet belongs to one element (boundary) or
    two (interior), (3) the elements are connected through shared facets, (4) each
    ridge of the boundary (a vertex in 2D, an edge in 3D) lies on exactly two boundary
    facets, which (5) do not fold onto each other (opposite normals, overlapping), and
    (6) no node lies on a boundary facet it is not a vertex of. Hanging nodes and
    interfaces meshed differently on their two sides fail (4), (5) or (6); separate
    parts, or parts touching only at a vertex or an edge, fail (3).
    """
    n_nodes = points.shape[0]
    sorted_cells = np.sort(cells, axis=1)
    collapsed = np.any(sorted_cells[:, 1:] == sorted_cells[:, :-1], axis=1)
    if np.any(collapsed):
        bad = np.flatnonzero(collapsed)
        raise InputError(field, f"{bad.size} element(s) use one node twice (e.g. element {bad[0]}, nodes "
                                f"{cells[bad[0]].tolist()})")
    _, _, counts = unique_rows(sorted_cells, n_nodes)
    if np.any(counts > 1):
        raise InputError(field, f"{int(np.sum(counts - 1))} element(s) repeat another element's nodes "
                                "(each element must appear once)")
    facets, owner, _ = element_facets(cells)
    uniq, inverse, counts = unique_rows(facets, n_nodes)
    if np.any(counts > 2):
        bad = np.flatnonzero(counts > 2)
        raise InputError(field, f"{bad.size} facet(s) are shared by 3 or more elements (overlapping or "
                                f"non-manifold elements), e.g. nodes {uniq[bad[0]].tolist()}")
    _check_connected(cells, owner, inverse, counts, n_nodes, field)
    boundary = counts[inverse] == 1
    bfacets, bowner = facets[boundary], owner[boundary]
    normals = outward_facet_normals(points, cells, bowner, bfacets)
    _check_boundary_ridges(points, bfacets, normals, n_nodes, field)
    check_hanging_nodes(points, bfacets, field)
    return uniq, counts


def _check_connected(cells, owner, inverse, counts, n_nodes, field) -> None:
    """One body: the elements connected through shared facets."""
    n_el = cells.shape[0]
    interior = counts[inverse] == 2
    order = np.argsort(inverse[interior], kind="stable")
    pairs = owner[interior][order].reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_el, n_el))
    n_parts, labels = connected_components(graph, directed=False)
    if n_parts == 1:
        return
    sizes = np.sort(np.bincount(labels))[::-1]
    shown = ", ".join(str(s) for s in sizes[:5]) + (", ..." if n_parts > 5 else "")
    # do the parts share nodes? then they touch at vertices or edges only
    node_part = np.full(n_nodes, -1)
    node_part[cells.ravel()] = np.repeat(labels, cells.shape[1])
    shared = np.any(node_part[cells] != labels[:, None])
    if shared:
        raise InputError(field, f"the mesh is {n_parts} parts ({shown} elements) that share nodes but no facet: they "
                                "touch only at vertices or edges, or meet at a non-conforming interface (hanging nodes, "
                                "faces split differently); it must be one body whose elements meet through shared "
                                "facets")
    raise InputError(field, f"the mesh has {n_parts} disconnected parts ({shown} elements); elastoplast solves one "
                            "body pressed by one rigid body: remove the extra parts, or mesh touching parts "
                            "conformally (gmsh: fragment the volumes so they share their interface)")


def _check_boundary_ridges(points, bfacets, normals, n_nodes, field) -> None:
    """(4) each boundary ridge on exactly two boundary facets, (5) without a fold."""
    d = points.shape[1]
    ridges, which, _ = element_facets(bfacets)  # a facet's (d-1)-subsets
    uniq, inverse, counts = unique_rows(ridges, n_nodes)
    ridge_name = "boundary node(s)" if d == 2 else "boundary edge(s)"
    if np.any(counts != 2):
        bad = np.flatnonzero(counts != 2)
        found = sorted(set(counts[bad].tolist()))
        raise InputError(field, f"the boundary is not a closed surface: {bad.size} {ridge_name} lie on "
                                f"{'/'.join(map(str, found))} boundary facets instead of 2, e.g. nodes "
                                f"{uniq[bad[0]].tolist()} (hanging nodes, an interface meshed differently on its "
                                "two sides, or parts touching along an edge)")
    order = np.argsort(inverse, kind="stable")
    pairs = which[order].reshape(-1, 2)
    cos = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]])
    folded = cos < -1.0 + 1e-8
    if np.any(folded):
        bad = np.flatnonzero(folded)
        raise InputError(field, f"the boundary folds back onto itself at {bad.size} {ridge_name} (two boundary facets "
                                f"overlap with opposite normals), e.g. nodes {uniq[bad[0]].tolist()}: the mesh is not "
                                "conforming (hanging nodes, or faces split differently on the two sides of an "
                                "interface)")


def check_hanging_nodes(points, bfacets, field, n_candidates: int = 8, tol: float = 1e-8) -> None:
    """(6) no boundary node lies on a boundary facet it is not a vertex of.

    For each boundary facet the ``d + n_candidates`` boundary nodes nearest its
    centroid (k-d tree) are tested: distance to the facet's line/plane at most
    ``tol`` times its longest edge, and barycentric coordinates within ``[-tol, 1 + tol]``.
    """
    from scipy.spatial import cKDTree

    d = points.shape[1]
    bnodes = np.unique(bfacets)
    if bnodes.size <= d:
        return
    X = points[bfacets]  # (nf, d, d)
    centroid = X.mean(axis=1)
    radius = np.linalg.norm(X - centroid[:, None], axis=2).max(axis=1)
    k = min(bnodes.size, d + n_candidates)
    dist, idx = cKDTree(points[bnodes]).query(centroid, k=k)
    cand = bnodes[idx]  # (nf, k)
    ok = (dist <= radius[:, None] * (1 + 1e-9)) & ~np.any(cand[:, :, None] == bfacets[:, None, :], axis=2)
    f, j = np.nonzero(ok)
    if f.size == 0:
        return
    q = points[cand[f, j]]
    P = X[f]
    e = [P[:, i] - P[:, 0] for i in range(1, d)]
    w = q - P[:, 0]
    le = local_edges(d - 1)
    h = np.linalg.norm(P[:, le[:, 0]] - P[:, le[:, 1]], axis=2).max(axis=1)
    if d == 2:
        t = np.einsum("ij,ij->i", w, e[0]) / np.einsum("ij,ij->i", e[0], e[0])
        off = np.linalg.norm(w - t[:, None] * e[0], axis=1)
        bary = np.stack([1 - t, t], axis=1)
    else:
        g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e[0], e[0]), (e[0], e[1]), (e[1], e[1])))
        r1, r2 = np.einsum("ij,ij->i", w, e[0]), np.einsum("ij,ij->i", w, e[1])
        det = g11 * g22 - g12 * g12
        s = (g22 * r1 - g12 * r2) / det
        t = (g11 * r2 - g12 * r1) / det
        off = np.linalg.norm(w - s[:, None] * e[0] - t[:, None] * e[1], axis=1)
        bary = np.stack([1 - s - t, s, t], axis=1)
    hanging = (off <= tol * h) & np.all(bary >= -tol, axis=1)
    if np.any(hanging):
        first = np.flatnonzero(hanging)[0]
        node = int(cand[f[first], j[first]])
        raise InputError(field, f"{np.unique(cand[f, j][hanging]).size} node(s) hang on boundary facets they are not "
                                f"vertices of, e.g. node {node} at {points[node].tolist()} on facet "
                                f"{bfacets[f[first]].tolist()}: the mesh is not conforming")


def check_facet_groups(uniq: np.ndarray, counts: np.ndarray, groups: Mapping[str, np.ndarray], n_nodes: int,
                       field: str, boundary_only: bool = True) -> None:
    """Every facet of every group must be a boundary facet of the body (with
    ``boundary_only=False``, a face of some element: facets in no group are ignored,
    but a facet that is no face would be an element silently dropped)."""
    for name, facets in groups.items():
        if len(facets) == 0:
            continue
        where = locate_rows(uniq, np.sort(facets, axis=1), n_nodes)
        missing = where < 0
        if np.any(missing):
            raise InputError(field, f"{int(missing.sum())} facet(s) of group {name!r} are not faces of any element, "
                                    f"e.g. nodes {facets[np.flatnonzero(missing)[0]].tolist()}")
        inside = counts[where] == 2
        if boundary_only and np.any(inside):
            raise InputError(field, f"{int(inside.sum())} facet(s) of group {name!r} lie inside the body (between two "
                                    "elements); boundary conditions act on boundary facets only")


# ----------------------------------------------------------------------------
# perfect plasticity on meshes that lock
# ----------------------------------------------------------------------------




def reorient(points: np.ndarray, cells: np.ndarray, field: str) -> np.ndarray:
    """``cells`` with every simplex positively oriented, or an InputError naming ``field``
    for a folded mesh. Elements listed clockwise (a mirrored half model, mirrored parts
    joined) are a valid geometry listed the other way round: their first two vertices
    are swapped, with a warning saying how many. A fold is told apart by the two
    elements of an interior facet (a conforming mesh, :func:`check_conforming`): in a
    valid mesh their opposite vertices lie on opposite sides of it whatever the listing;
    in a folded one some pair lies on the same side, and the mesh is refused."""
    X = points[cells]
    det = np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))
    negative = det < 0
    if not np.any(negative) or np.all(negative | (det == 0)):
        return cells  # one orientation throughout (a clockwise one is handled by the volumes' sign)
    facets, owner, local = element_facets(cells)
    _, inverse, counts = unique_rows(facets, points.shape[0])
    opposite = points[cells[owner, local]]
    F = points[facets]
    side = np.sign(np.linalg.det(np.concatenate([F[:, 1:] - F[:, :1], (opposite - F[:, 0])[:, None]], axis=1)))
    interior = np.flatnonzero(counts[inverse] == 2)
    order = interior[np.argsort(inverse[interior], kind="stable")].reshape(-1, 2)
    folded = (side[order[:, 0]] == side[order[:, 1]]) & (side[order[:, 0]] != 0)
    if np.any(folded):
        first = owner[order[np.flatnonzero(folded)[0]]].tolist()
        raise InputError(field, f"the mesh folds over itself: {int(folded.sum())} interior facet(s) have both their "
                                f"elements on one side (e.g. elements {first}); {int(negative.sum())} of "
                                f"{cells.shape[0]} elements are listed with the opposite orientation")
    oriented = cells.copy()
    oriented[negative, :2] = oriented[negative, 1::-1]
    warnings.warn(f"{int(negative.sum())} of {cells.shape[0]} elements were listed with the opposite orientation "
                  "(as a mirrored part is): reoriented")
    return oriented


def check_axisymmetric(value, mesh) -> bool:
    """``mesh.axisymmetric``: a boolean, true only for a 2D mesh (the meridian plane)."""
    if not isinstance(value, bool):
        raise InputError("mesh.axisymmetric", f"must be true or false, got {short_repr(value)}")
    if value and mesh.dim != 2:
        raise InputError("mesh.axisymmetric", "an axisymmetric model is a 2D mesh of the meridian plane (r, z); "
                                              f"this mesh is {mesh.dim}D")
    return value
