"""Mesh topology built once from the simplices: integer keys of vertex rows, local edge
tables, facets, boundary facets, normals, facet connectivity."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from elastoplast.errors import InputError

# ----------------------------------------------------------------------------
# integer keys of vertex rows
# ----------------------------------------------------------------------------


def keys_fit(n: int, width: int) -> bool:
    """Whether rows of ``width`` entries below ``n`` have distinct int64 :func:`row_keys`."""
    return max(int(n), 1) ** int(width) < 2**62


def row_keys(rows: np.ndarray, n: int) -> np.ndarray:
    """One int64 per row (last axis) of integers in ``[0, n)``: the row read as digits
    in base ``n``, so keys order like the rows (lexicographically); see :func:`keys_fit`."""
    rows = np.asarray(rows)
    key = rows[..., 0].astype(np.int64)
    for j in range(1, rows.shape[-1]):
        key = key * np.int64(n) + rows[..., j]
    return key


def pair_keys(i: np.ndarray, j: np.ndarray, n: int) -> np.ndarray:
    """:func:`row_keys` of the unordered pairs ``{i, j}`` (elementwise, any shape):
    one int64 per edge, ``min * n + max``."""
    return row_keys(np.stack([np.minimum(i, j), np.maximum(i, j)], axis=-1), n)


def locate_keys(table: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Index in the sorted int64 ``table`` of each of ``keys``, -1 where absent."""
    if table.size == 0:
        return np.full(np.shape(keys), -1, dtype=np.int64)
    at = np.minimum(np.searchsorted(table, keys), table.size - 1)
    return np.where(table[at] == keys, at, -1)


def unique_rows(a: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(unique rows, inverse, counts)`` of an integer array with entries in ``[0, n)``,
    the unique rows in lexicographic order.

    Rows are compared by their :func:`row_keys` when those fit (much faster than
    ``np.unique(axis=0)``), otherwise as rows.
    """
    a = np.ascontiguousarray(a, dtype=np.int64)
    if a.shape[0] == 0:
        return a, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if keys_fit(n, a.shape[1]):
        _, first, inverse, counts = np.unique(row_keys(a, n), return_index=True, return_inverse=True,
                                              return_counts=True)
        return a[first], inverse.ravel(), counts
    uniq, inverse, counts = np.unique(a, axis=0, return_inverse=True, return_counts=True)
    return uniq, inverse.ravel(), counts


def row_classes(parts, n: int) -> tuple[np.ndarray, int]:
    """``(inverse, number of distinct rows)`` of the rows of the integer arrays ``parts`` (an
    iterable of arrays of one width, entries in ``[0, n)``, read once, taken in order):
    :func:`unique_rows`' inverse of their concatenation without the unique rows, and, where
    the :func:`row_keys` fit, without the rows themselves at once (each part becomes its keys
    as it comes: the facets of a large mesh, where only each row's class is needed)."""
    keys, rows = [], []
    for part in parts:
        part = np.asarray(part, dtype=np.int64)
        if keys_fit(n, part.shape[1]):
            keys.append(row_keys(part, n))
        else:
            rows.append(part)
    if rows:  # one width for all parts: the keys fit for all of them or for none
        _, inverse = np.unique(np.concatenate(rows), axis=0, return_inverse=True)
    elif keys:
        _, inverse = np.unique(np.concatenate(keys), return_inverse=True)
    else:
        return np.zeros(0, dtype=np.int64), 0
    inverse = inverse.ravel()
    return inverse, int(inverse.max(initial=-1)) + 1


def locate_rows(table: np.ndarray, queries: np.ndarray, n: int) -> np.ndarray:
    """Index in ``table`` (unique rows) of each row of ``queries``, -1 where absent."""
    inverse, _ = row_classes([table, queries], n)
    where = np.full(inverse.max(initial=-1) + 1, -1, dtype=np.int64)
    where[inverse[: len(table)]] = np.arange(len(table))
    return where[inverse[len(table):]]


# ----------------------------------------------------------------------------
# edges, facets and their normals
# ----------------------------------------------------------------------------


def local_edges(dim: int) -> np.ndarray:
    """The edges of a ``dim``-simplex as pairs ``(i, j)``, ``i < j``, of its local
    vertices: ``(dim (dim+1) / 2, 2)`` in lexicographic order."""
    return np.stack(np.triu_indices(dim + 1, 1), axis=1)


def element_edges(cells: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's edges, each once: ``(edges (n_edges, 2), element_edge (n_el, n_local))``.
    Each edge is its ``(lo, hi)``-sorted vertex pair, the edges in lexicographic order of
    those pairs (a stable numbering: the same mesh always gives the same one), and
    ``element_edge[e, j]`` is the edge of element ``e``'s local edge ``j`` of
    :func:`local_edges`. The one edge table of every user (the P2 velocities of the
    limit load, the crossed-pattern check, bisection's labelling)."""
    cells = np.asarray(cells, dtype=np.int64)
    pairs = local_edges(cells.shape[1] - 1)
    edges, element_edge, _ = unique_rows(np.sort(cells[:, pairs], axis=2).reshape(-1, 2), n_nodes)
    return edges, element_edge.reshape(cells.shape[0], len(pairs))


def element_facets(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All facets of all elements, each row sorted: ``(facets (n_el*(d+1), d),
    element of each, local index of the vertex each is opposite to)``; facet ``j`` of
    element ``e`` is row ``j * n_el + e``."""
    n, q = cells.shape
    facets = np.sort(np.concatenate([cells[:, v] for v in facet_vertices(q)], axis=0), axis=1)
    return facets, np.tile(np.arange(n), q), np.repeat(np.arange(q), n)


def facet_vertices(q: int) -> np.ndarray:
    """``(q, q-1)``: the local vertices of the facet opposite each vertex of a simplex of ``q``
    vertices, in increasing order (facet ``j`` of :func:`element_facets`)."""
    return np.array([[i for i in range(q) if i != j] for j in range(q)], dtype=np.int64)


def boundary_facets(cells: np.ndarray, n_nodes: int | None = None) -> np.ndarray:
    """Facets that belong to exactly one element, each row sorted."""
    facets, _, _ = element_facets(cells)
    uniq, _, counts = unique_rows(facets, int(cells.max(initial=0)) + 1 if n_nodes is None else n_nodes)
    return uniq[counts == 1]


def facet_normals(X: np.ndarray) -> np.ndarray:
    """Normals ``(m, d)`` of facets with vertex coordinates ``X (m, d, d)``, from edge
    vectors: the perpendicular ``(t_y, -t_x)`` of the edge ``t`` in 2D, the cross
    product of two edges in 3D. Their length is the facet's measure times ``(d-1)!``
    and their direction follows the order of the vertices."""
    if X.shape[1] == 2:
        t = X[:, 1] - X[:, 0]
        return np.stack([t[:, 1], -t[:, 0]], axis=1)
    return np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])


def facet_measure(X: np.ndarray) -> np.ndarray:
    """Measure of facets with vertex coordinates ``X (m, d, d)`` (length in 2D, area in 3D)."""
    size = np.linalg.norm(facet_normals(X), axis=1)
    return size if X.shape[1] == 2 else 0.5 * size


def outward_facet_normals(points: np.ndarray, cells: np.ndarray, elements: np.ndarray,
                          facets: np.ndarray) -> np.ndarray:
    """Unit normals ``(m, d)`` of ``facets (m, d)`` (node indices) of ``elements``, from
    edge vectors (:func:`facet_normals`) and oriented away from the element's centroid."""
    X = points[facets]
    nrm = facet_normals(X)
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), np.finfo(float).tiny)
    away = X.mean(axis=1) - points[cells[elements]].mean(axis=1)
    return nrm * np.sign(np.einsum("md,md->m", nrm, away))[:, None]


# ----------------------------------------------------------------------------
# facet connectivity
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class FacetTopology:
    """Facets of a simplicial mesh, classified by the problem's facet groups.

    Local facet ``i`` of an element is the one opposite its local vertex ``i``.
    Facet nodes are sorted ascending; ``*_vertices`` give, for each facet node, its
    local vertex index in the element (so vertex values line up across a facet).

    * interior facets: ``interior_elements (n_if, 2)``, ``interior_local (n_if, 2)``,
      ``interior_vertices (n_if, 2, d)``, ``interior_nodes (n_if, d)``;
    * boundary facets: ``boundary_elements (n_bf,)``, ``boundary_local``,
      ``boundary_vertices (n_bf, d)``, ``boundary_nodes (n_bf, d)``,
      ``fixed (n_bf, d)`` the displacement components fixed on the facet (clamped:
      all; ``fix_component`` c: c), ``contact (n_bf,)`` Γ0 facets.

    The traction components that must vanish on a boundary facet are
    :attr:`zero_traction`: those neither fixed nor the contact component ``d``
    of a Γ0 facet.
    """

    interior_elements: np.ndarray
    interior_local: np.ndarray
    interior_vertices: np.ndarray
    interior_nodes: np.ndarray
    boundary_elements: np.ndarray
    boundary_local: np.ndarray
    boundary_vertices: np.ndarray
    boundary_nodes: np.ndarray
    fixed: np.ndarray
    contact: np.ndarray
    #: group facets that are interior facets of the mesh (they carry no condition)
    ignored_interior: int = 0

    @property
    def dim(self) -> int:
        return self.boundary_nodes.shape[1]

    @property
    def contact_index(self) -> np.ndarray:
        """Boundary-facet indices of the Γ0 facets, in the order of ``contact_facets``."""
        return np.flatnonzero(self.contact)

    @property
    def contact_facets(self) -> np.ndarray:
        """Node indices ``(n_cf, d)`` of the Γ0 facets."""
        return self.boundary_nodes[self.contact]

    @property
    def zero_traction(self) -> np.ndarray:
        """``(n_bf, d)``: traction components that must vanish."""
        contact_comp = np.zeros_like(self.fixed)
        contact_comp[:, -1] = self.contact
        return ~self.fixed & ~contact_comp


def local_vertex_indices(cells: np.ndarray, elements: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Local vertex index in ``cells[elements]`` of each node of ``nodes (m, d)``."""
    return np.argmax(cells[elements][:, None, :] == nodes[:, :, None], axis=2)


def facet_topology(mesh, boundary) -> FacetTopology:
    """Interior and boundary facets of a :class:`~elastoplast.mesh.base.Mesh`, and each boundary facet's
    condition under a :class:`~elastoplast.problem.definition.Boundary` (vectorised).

    A boundary facet may belong to several groups: its fixed components are the
    union over its groups (clamped fixes all), and it is a contact facet if any of
    its groups is a contact group. Refuses group facets that are no face of any
    element, non-manifold meshes and an empty contact zone.
    """
    cells, d = mesh.cells, mesh.dim
    n_el, q = cells.shape
    # facet j of element e is row j * n_el + e (as element_facets'), never all formed at once: a
    # split mesh has millions, and only their classes and the rows kept below are needed
    opposite = facet_vertices(q)
    n_faces = n_el * q

    def facet_rows(r):
        return np.sort(cells[(r % n_el)[:, None], opposite[r // n_el]], axis=1)

    named = [("clamped", name) for name in boundary.clamped] + [("contact", name) for name in boundary.contact]
    named += [(f"fix_component.{'xyz'[c]}", name) for c, names in boundary.fix_component.items() for name in names]
    group_faces = [np.sort(np.asarray(mesh.groups[name], dtype=np.int64).reshape(-1, d), axis=1) for _, name in named]
    n_ids = max([mesh.n_nodes] + [int(g.max(initial=-1)) + 1 for g in group_faces])
    inv, n_unique = row_classes(itertools.chain((np.sort(cells[:, opposite[j]], axis=1) for j in range(q)), group_faces),
                                n_ids)
    fid = inv[:n_faces]
    counts = np.bincount(fid, minlength=n_unique)
    if np.any(counts > 2):
        raise InputError("mesh", f"{int(np.sum(counts > 2))} facet(s) shared by more than two elements (non-manifold mesh)")

    order = np.argsort(fid, kind="stable")  # each temporary below is released once used
    two = counts[fid[order]] == 2
    paired = order[two]
    first, second = paired[0::2], paired[1::2]
    one = order[~two]
    del order, two
    i_nodes = facet_rows(first)
    b_nodes = facet_rows(one)
    i_elem = np.stack([first % n_el, second % n_el], axis=1)
    i_loc = np.stack([first // n_el, second // n_el], axis=1)
    i_vert = np.empty((first.size, 2, d), dtype=np.int64)
    for s in range(2):
        i_vert[:, s] = local_vertex_indices(cells, i_elem[:, s], i_nodes)

    b_elem, b_loc = one % n_el, one // n_el
    b_vert = local_vertex_indices(cells, b_elem, b_nodes)
    position = -np.ones(n_unique, dtype=np.int64)
    position[fid[one]] = np.arange(one.size)
    interior = np.zeros(n_unique, dtype=bool)
    interior[fid[first]] = True

    fixed = np.zeros((one.size, d), dtype=bool)
    contact = np.zeros(one.size, dtype=bool)
    start = n_faces
    ignored = 0
    for (key, name), gf in zip(named, group_faces):
        ids = inv[start: start + gf.shape[0]]
        start += gf.shape[0]
        if np.any(counts[ids] == 0):
            raise InputError(f"boundary.{key}", f"group {name!r} has {int(np.sum(counts[ids] == 0))} facet(s) that are no face of any element")
        ignored += int(np.sum(interior[ids]))
        b = position[ids[~interior[ids]]]
        if key == "clamped":
            fixed[b] = True
        elif key == "contact":
            contact[b] = True
        else:
            fixed[b, "xyz".index(key[-1])] = True
    if not contact.any():
        raise InputError("boundary.contact", f"the contact zone {list(boundary.contact)} has no boundary facets")
    return FacetTopology(i_elem, i_loc, i_vert, i_nodes, b_elem, b_loc, b_vert, b_nodes, fixed, contact, ignored)
