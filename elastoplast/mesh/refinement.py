"""Conforming local refinement of triangle and tetrahedral meshes by bisection.

Scheme
------
Every simplex carries a *refinement edge*, stored as its first two vertices
``(a, b)``. Bisecting it inserts the midpoint ``z`` of ``ab`` and replaces the
simplex by its two halves ``{a, z, ...}`` and ``{b, z, ...}``.

* 2D: newest-vertex bisection (Sewell 1972, Mitchell 1989). A triangle ``(a, b, c)`` has the
  children ``(a, c, z)`` and ``(b, c, z)``: each child's refinement edge is the
  edge opposite its newest vertex ``z``.
* 3D: the marked tetrahedra of Arnold, Mukherjee & Pouly (SIAM J. Sci. Comput.
  22, 2000). Besides the refinement edge ``ab`` each face carries a marked edge,
  the same one seen from both tetrahedra sharing the face, and the refinement
  edge is the marked edge of both faces containing it. With ``c, d`` the other
  two vertices, a tetrahedron stores the marked edge of its face ``acd``
  (``ac``, ``ad`` or ``cd``: code 0, 1, 2) and of its face ``bcd`` (``bc``,
  ``bd``, ``cd``) and a flag. The child ``{a, c, d, z}`` takes the marked edge
  of ``acd`` as its refinement edge; the halves of the faces ``abc``, ``abd``
  are marked at the edge opposite ``z`` (newest-vertex bisection of each face);
  the new face ``cdz`` is marked at ``cd``, except when the parent is *planar
  flagged* (its four marked edges lie in one face ``a b p``), where it is
  marked at ``zp``. Children of a planar unflagged parent are flagged, all
  others are not. This is Maubach's bisection (SIAM J. Sci. Comput. 16, 1995;
  Traxler, Computing 59, 1997) in the notation of Stevenson (Math. Comp. 77,
  2008): the types planar-unflagged,
  planar-flagged and the type whose two other marked edges are skew are his
  tags 1, 2, 0, and every child of any tetrahedron is of one of these three
  types.

Initial labelling: a strict global order on the edges (squared length, then
the node numbers), the refinement edge of each simplex is its largest edge and
the marked edge of each face is its largest edge. Faces shared by two
tetrahedra thus get the same mark. On the package's ``box`` meshes (Kuhn
simplices of boxes, reflected per layer) this reproduces Maubach's labelling:
the refinement edge is the box diagonal, the face marks are the face
diagonals, neighbours are reflected neighbours, and a uniform refinement
(three bisections per tetrahedron) gives exactly 8 children of half size
with no extra closure. The ``rectangle``/``crossed`` 2D meshes get the box
diagonal or the square's side, also compatible.

Why shapes stay bounded: bisection commutes with affine maps (midpoints and
the combinatorial rules are affine-invariant), so the descendants of a simplex
``T`` are the images under the affine map ``A_T`` of the descendants of a
reference simplex with the same labelling. For the labelled simplices that
occur after the first bisection (the three types above) these are descendants
of a Kuhn simplex, which repeat up to similarity after ``d`` bisections
(Maubach; Arnold et al. section 4). Hence each initial simplex has only
finitely many similarity classes of descendants and the shape constant is
bounded below by one depending on ``cond(A_T)`` only. In 2D newest-vertex
bisection creates at most four similarity classes per initial triangle
whatever the initial refinement edge.

Closure: a simplex is bisected when it is marked (``bisections`` times,
default ``d``) or when one of its edges has been bisected elsewhere (a hanging
node). Rounds repeat until no simplex has a hanging node; each round is
vectorised over all simplices it bisects. The result is the coarsest
conforming mesh of the bisection forest that contains the requested
bisections (every bisection the closure adds is needed by any such mesh).
The closure ends for compatible labellings (Maubach, Stevenson), in 2D for any
refinement edges, and for the marked tetrahedra of Arnold et al. on any
conforming initial mesh (their termination result); a round limit turns a
closure that does not end into a ``RuntimeError``.

Facet groups follow their facets: every face of a simplex carries the index of
the group facet it lies in (or -1), children inherit it face by face, and the
final group facets are the faces that carry a tag, oriented like the facet they
came from. New nodes on the boundary are midpoints of boundary edges, so they
lie on the (flat) facet; a facet in ``x_d = 0`` stays in it exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastoplast.limits import check_mesh_size
from elastoplast.errors import InputError, expect
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.topology import (
    element_edges,
    facet_measure,
    facet_normals,
    keys_fit,
    local_edges,
    locate_keys,
    pair_keys,
    row_keys,
    unique_rows,
)
from elastoplast.options import Spec, check_array, check_value

#: most bisections of one element in one call (each halves it; 60 already exceed any memory)
MAX_BISECTIONS = 60

#: base of the edge keys (:func:`~elastoplast.mesh.topology.pair_keys`): fixed, not the node count,
#: since the keys of bisected edges are kept while nodes are added
EDGE_BASE = 2**32

# Children as positions in [a, b, (c, d,) z] of the parent, in the child's own
# labelled order; first index: the marked edge of the face opposite b (child 1)
# or opposite a (child 2), codes 0: ac|bc, 1: ad|bd, 2: cd (3D only).
_CHILD1 = {2: np.array([[0, 2, 3]]), 3: np.array([[0, 2, 3, 4], [0, 3, 2, 4], [2, 3, 0, 4]])}
_CHILD2 = {2: np.array([[1, 2, 3]]), 3: np.array([[1, 2, 3, 4], [1, 3, 2, 4], [2, 3, 1, 4]])}
# Orientation of each child relative to its parent. Replacing b (or a) by z
# keeps the sign (z has barycentric weight 1/2 on the vertex it replaces), so
# (a, z, c, d) and (z, b, c, d) have the parent's sign; the rows above permute
# those, e.g. (a, c, d, z) is a 3-cycle of (a, z, c, d), (b, c, d, z) a 4-cycle
# of (z, b, c, d).
_SIGN1 = {2: np.array([-1]), 3: np.array([1, -1, 1])}
_SIGN2 = {2: np.array([1]), 3: np.array([-1, 1, -1])}


@dataclass(frozen=True)
class BisectionState:
    """What bisection needs to know about a mesh between calls.

    ``cells (n_el, d+1)``: the mesh's simplices in labelled order, the
    refinement edge first (``cells[:, :2]``); ``orientation (n_el,)``: the
    sign of ``det[x1 - x0, ..., xd - x0]`` in that order; ``marks (n_el, 2)``: in 3D the
    marked edge of the face opposite ``cells[:, 1]`` (0: ``ac``, 1: ``ad``,
    2: ``cd`` with ``a, b, c, d = cells.T``) and of the face opposite
    ``cells[:, 0]`` (0: ``bc``, 1: ``bd``, 2: ``cd``), zeros in 2D;
    ``flagged (n_el,)``: the planar-flagged type (3D); ``generation (n_el,)``:
    bisections since the initial mesh; ``node_parents (n_nodes, 2)``: the edge
    each node bisected, ``-1`` for the initial nodes (new nodes are numbered
    after their parents, which gives :func:`prolong_p1`).
    """

    cells: np.ndarray
    orientation: np.ndarray
    marks: np.ndarray
    flagged: np.ndarray
    generation: np.ndarray
    node_parents: np.ndarray

    @property
    def dim(self) -> int:
        return self.cells.shape[1] - 1

    @property
    def n_elements(self) -> int:
        return self.cells.shape[0]

    @property
    def n_nodes(self) -> int:
        return self.node_parents.shape[0]


# ----------------------------------------------------------------------------
# initial labelling
# ----------------------------------------------------------------------------


def _check_mesh(mesh: Mesh) -> int:
    expect(mesh, Mesh, "mesh", "ep.structured_mesh, ep.read_mesh or problem.mesh")
    d = mesh.dim
    if d not in (2, 3) or mesh.cells.ndim != 2 or mesh.cells.shape[1] != d + 1:
        raise InputError("mesh", f"refinement needs triangles in 2D or tetrahedra in 3D, got cells of shape {mesh.cells.shape} in {d}D")
    if mesh.n_nodes >= 2**31:
        raise InputError("mesh", f"{mesh.n_nodes} nodes: refinement numbers edges by two 32-bit node indices")
    return d


def initial_state(mesh: Mesh) -> BisectionState:
    """Label an arbitrary conforming mesh: refinement edge of every simplex and
    marked edge of every face = its largest edge in the global order
    (squared length, smaller node, larger node)."""
    d = _check_mesh(mesh)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    n = cells.shape[0]
    le = local_edges(d)
    p, q = cells[:, le[:, 0]], cells[:, le[:, 1]]  # (n, n_edges)
    # the edge numbers order the edges as their (smaller node, larger node) pairs do
    _, keys = element_edges(cells, mesh.n_nodes)
    # the same bits for an edge in every simplex: always (larger node - smaller node)
    diff = mesh.points[np.maximum(p, q)] - mesh.points[np.minimum(p, q)]
    length2 = np.einsum("...i,...i->...", diff, diff)
    del p, q, diff

    def largest(cols: np.ndarray) -> np.ndarray:
        """Position of the largest edge (length2, then key) among ``cols[t]``."""
        l2, k = np.take_along_axis(length2, cols, 1), np.take_along_axis(keys, cols, 1)
        return np.argmax(np.where(l2 == l2.max(axis=1, keepdims=True), k, -1), axis=1)

    ref = largest(np.broadcast_to(np.arange(le.shape[0]), keys.shape))
    # local order (a, b, others ascending) for each choice of refinement edge
    perms = np.array([[i, j] + [k for k in range(d + 1) if k not in (i, j)] for i, j in le])
    labelled = np.take_along_axis(cells, perms[ref], axis=1)
    marks = np.zeros((n, 2), dtype=np.int8)
    if d == 3:
        # ac, ad, cd and bc, bd, cd as local edges of the input order
        where = {(i, j): e for e, (i, j) in enumerate(le)}
        edge = lambda p, q: where[(min(p, q), max(p, q))]  # noqa: E731
        opposite_b = np.array([[edge(a, c), edge(a, e), edge(c, e)] for a, b, c, e in perms])
        opposite_a = np.array([[edge(b, c), edge(b, e), edge(c, e)] for a, b, c, e in perms])
        marks[:, 0] = largest(opposite_b[ref])
        marks[:, 1] = largest(opposite_a[ref])
    vol = signed_volumes(mesh.points, labelled)
    if np.any(vol == 0):
        raise InputError("mesh", f"{int(np.sum(vol == 0))} element(s) of zero volume, first: element {int(np.argmax(vol == 0))}")
    return BisectionState(
        cells=labelled,
        orientation=np.where(vol > 0, 1, -1).astype(np.int8),
        marks=marks,
        flagged=np.zeros(n, dtype=bool),
        generation=np.zeros(n, dtype=np.int32),
        node_parents=-np.ones((mesh.n_nodes, 2), dtype=np.int64),
    )


# ----------------------------------------------------------------------------
# facet groups
# ----------------------------------------------------------------------------


def _facet_tags(mesh: Mesh, cells: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``(tags (n_el, d+1), members)``: ``tags[t, i]`` numbers the distinct
    group facet that the face of ``t`` opposite its local vertex ``i`` is (-1:
    none); ``members[name]`` gives that number for each row of the group."""
    n, d = cells.shape[0], cells.shape[1] - 1
    tags = -np.ones((n, d + 1), dtype=np.int64)
    if not mesh.groups:
        return tags, {}
    for name, g in mesh.groups.items():
        if np.ndim(g) != 2 or np.shape(g)[1] != d:
            raise InputError(f"mesh.groups.{name}", f"facets of a {d}D mesh have {d} nodes, got an array of shape {np.shape(g)}")
    rows = np.sort(np.concatenate([np.asarray(g, dtype=np.int64) for g in mesh.groups.values()]), axis=1)
    facets, _, _ = unique_rows(rows, mesh.n_nodes)
    nodes = np.unique(facets)
    local = -np.ones(mesh.n_nodes, dtype=np.int64)
    local[nodes] = np.arange(nodes.size)
    if not keys_fit(nodes.size, d):  # pragma: no cover - beyond 2 million boundary nodes
        raise InputError("mesh.groups", f"{nodes.size} group nodes: too many to key facets in 64 bits")
    fkeys = row_keys(local[facets], nodes.size)  # sorted, as facets are
    on = local[cells] >= 0
    cand = np.flatnonzero(on.sum(axis=1) >= d)
    found = np.zeros(facets.shape[0], dtype=bool)
    for i in range(d + 1):
        face = np.delete(cells[cand], i, axis=1)
        inside = np.all(local[face] >= 0, axis=1)
        el = cand[inside]
        pos = locate_keys(fkeys, row_keys(np.sort(local[face[inside]], axis=1), nodes.size))
        hit = pos >= 0
        # an interior facet would be met from two elements: tag it once
        pos, el = pos[hit], el[hit]
        fresh = ~found[pos]
        pos, first = np.unique(pos[fresh], return_index=True)
        tags[el[fresh][first], i] = pos
        found[pos] = True
    if not found.all():
        bad = facets[np.flatnonzero(~found)[0]]
        raise InputError("mesh.groups", f"{int((~found).sum())} group facet(s) are no face of any element, first: nodes {bad.tolist()}")
    members = {}
    for name, g in mesh.groups.items():
        members[name] = locate_keys(fkeys, row_keys(np.sort(local[np.asarray(g, dtype=np.int64).reshape(-1, d)],
                                                            axis=1), nodes.size))
    return tags, members


def _refined_groups(mesh: Mesh, points: np.ndarray, cells: np.ndarray, tags: np.ndarray,
                    members: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each group facet replaced by the faces that carry its tag, in the order
    of the group's rows and oriented like the facet they refine."""
    d = cells.shape[1] - 1
    el, fi = np.nonzero(tags >= 0)
    tag = tags[el, fi]
    others = np.array([[k for k in range(d + 1) if k != i] for i in range(d + 1)])
    faces = np.take_along_axis(cells[el], others[fi], axis=1)
    order = np.argsort(tag, kind="stable")
    tag, faces = tag[order], faces[order]
    n_distinct = max((int(m.max()) + 1 for m in members.values() if m.size), default=0)
    count = np.bincount(tag, minlength=n_distinct)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    groups = {}
    for name, idx in members.items():
        c = count[idx]
        total = int(c.sum())
        offset = np.arange(total) - np.repeat(np.cumsum(c) - c, c)
        rows = faces[np.repeat(start[idx], c) + offset]
        parent_rows = np.asarray(mesh.groups[name], dtype=np.int64).reshape(-1, d)[np.repeat(np.arange(idx.size), c)]
        flip = np.einsum("ij,ij->i", facet_normals(points[rows]), facet_normals(mesh.points[parent_rows])) < 0
        rows[flip, :2] = rows[flip, 1::-1]
        groups[name] = rows
    return groups


# ----------------------------------------------------------------------------
# refinement
# ----------------------------------------------------------------------------


def _marked_mask(marked, n: int) -> np.ndarray:
    m = np.asarray(marked)
    if m.dtype == bool:
        if m.shape != (n,):
            raise InputError("marked", f"a boolean mask needs one entry per element ({n}), got shape {m.shape}")
        return m.copy()
    if m.size == 0:
        return np.zeros(n, dtype=bool)
    if m.ndim != 1 or not np.issubdtype(m.dtype, np.integer):
        raise InputError("marked", f"give a boolean mask or element indices, got an array of {m.dtype} with shape {m.shape}")
    if m.min() < 0 or m.max() >= n:
        raise InputError("marked", f"element indices must lie in [0, {n}), got {int(m.min())}..{int(m.max())}")
    mask = np.zeros(n, dtype=bool)
    mask[m] = True
    return mask


def _check_state(state: BisectionState, mesh: Mesh) -> None:
    expect(state, BisectionState, "state", "the state ep.refine returned with this mesh, or None")
    ok = (state.cells.shape == mesh.cells.shape and state.n_nodes == mesh.n_nodes
          and np.array_equal(np.sort(state.cells, axis=1), np.sort(mesh.cells, axis=1)))
    if not ok:
        raise InputError("state", "the bisection state does not belong to this mesh (pass the state refine returned with it)")


def _has_bisected_edge(cells: np.ndarray, keys: np.ndarray, endpoint: np.ndarray) -> np.ndarray:
    """Which simplices have an edge listed in the sorted ``keys``; only edges
    whose two ends are marked in ``endpoint`` are looked up."""
    le = local_edges(cells.shape[1] - 1)
    p, q = cells[:, le[:, 0]], cells[:, le[:, 1]]
    el, e = np.nonzero(endpoint[p] & endpoint[q])
    out = np.zeros(cells.shape[0], dtype=bool)
    out[el[locate_keys(keys, pair_keys(p[el, e], q[el, e], EDGE_BASE)) >= 0]] = True
    return out


def signed_volumes(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``det[x1 - x0, ..., xd - x0] / d!`` for each simplex (positive when
    counter-clockwise / right-handed)."""
    x0 = points[cells[:, 0]]
    e = [points[cells[:, i]] - x0 for i in range(1, cells.shape[1])]
    if cells.shape[1] == 3:
        return 0.5 * (e[0][:, 0] * e[1][:, 1] - e[0][:, 1] * e[1][:, 0])
    u, v, w = e
    return (u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1]) - u[:, 1] * (v[:, 0] * w[:, 2] - v[:, 2] * w[:, 0])
            + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0])) / 6.0


def refine(mesh: Mesh, marked, state: BisectionState | None = None, *,
           bisections: int | None = None) -> tuple[Mesh, BisectionState, np.ndarray]:
    """Bisect the ``marked`` simplices ``bisections`` times each (default
    ``d``: children of half the size for Kuhn simplices, 4 triangles or 8
    tetrahedra per marked element) and every other simplex the closure needs
    for a conforming mesh.

    ``marked``: boolean mask ``(n_el,)`` or element indices. ``state``: the
    labelling returned by the previous call on this mesh (``None``: label the
    mesh with :func:`initial_state`). Returns ``(new_mesh, new_state,
    parent)``: new nodes are appended after the old ones (each the midpoint of
    ``new_state.node_parents[i]``), cells are positively oriented, every facet
    group is replaced by its refinement, and ``parent[t]`` is the old element
    the new element ``t`` lies in (P0 data transfer: ``values[parent]``).
    """
    d = _check_mesh(mesh)
    if state is None:
        state = initial_state(mesh)
    else:
        _check_state(state, mesh)
    k = d if bisections is None else check_value("bisections", bisections, Spec(int, "", lo=1, hi=MAX_BISECTIONS))
    n = mesh.n_elements
    mask = _marked_mask(marked, n)
    # each marked element leaves at least 2^k children: refuse what cannot fit before allocating
    least = n + int(mask.sum()) * (2**k - 1)
    check_mesh_size(d, least // (2 if d == 2 else 6) + 1, least, 0, "bisections",
                    f"bisecting {int(mask.sum()):,} element(s) {k} times", "mark fewer elements or bisect fewer times")
    todo = np.where(mask, k, 0).astype(np.int16)

    # per-element arrays, grown in place: a bisected element's first child
    # takes its slot, the second is appended
    el = {"cells": state.cells.copy(), "sign": state.orientation.copy(), "marks": state.marks.copy(),
          "flagged": state.flagged.copy(), "gen": state.generation.copy(), "origin": np.arange(n),
          "tags": None, "todo": todo}
    el["tags"], members = _facet_tags(mesh, el["cells"])
    points = np.asarray(mesh.points, dtype=float)
    parents = [state.node_parents]
    keys = np.zeros(0, dtype=np.int64)  # bisected edges (sorted) and their midpoints
    mids = np.zeros(0, dtype=np.int64)
    pending = np.flatnonzero(todo > 0)  # elements with bisections left
    check = np.zeros(0, dtype=np.int64)  # elements that may carry a hanging node
    endpoint = np.zeros(mesh.n_nodes, dtype=bool)  # nodes at an end of a bisected edge
    child1, child2, sign1, sign2 = _CHILD1[d], _CHILD2[d], _SIGN1[d], _SIGN2[d]
    max_rounds = 100 + 10 * (int(state.generation.max(initial=0)) + k)
    n_el = n  # elements in use; the arrays in el have room for more
    for _ in range(max_rounds):
        cells = el["cells"]
        if check.size and keys.size:
            is_pending = np.zeros(n_el, dtype=bool)
            is_pending[pending] = True
            cand = check[~is_pending[check]]
            hanging = cand[_has_bisected_edge(cells[cand], keys, endpoint)]
            B = np.concatenate([pending, hanging])
        else:
            B = pending
        if B.size == 0:
            break
        # midpoints of the refinement edges: existing ones, then new nodes
        ek = pair_keys(cells[B, 0], cells[B, 1], EDGE_BASE)
        pos = locate_keys(keys, ek)
        z = -np.ones(B.size, dtype=np.int64)
        hit = pos >= 0
        z[hit] = mids[pos[hit]]
        miss = z < 0
        new_keys, inv = np.unique(ek[miss], return_inverse=True)
        new_ids = points.shape[0] + np.arange(new_keys.size)
        z[miss] = new_ids[inv]
        lo, hi = np.divmod(new_keys, EDGE_BASE)
        points = np.concatenate([points, 0.5 * (points[lo] + points[hi])])
        endpoint = np.concatenate([endpoint, np.zeros(new_keys.size, dtype=bool)])
        endpoint[lo] = endpoint[hi] = True
        parents.append(np.stack([lo, hi], axis=1))
        at = np.searchsorted(keys, new_keys)
        keys, mids = np.insert(keys, at, new_keys), np.insert(mids, at, new_ids)

        # children, in their own labelled order
        ext = np.concatenate([cells[B], z[:, None]], axis=1)
        ma, mb = el["marks"][B, 0].astype(np.int64), el["marks"][B, 1].astype(np.int64)
        p1, p2 = child1[ma], child2[mb]
        t = el["tags"][B]
        none = -np.ones((B.size, 1), dtype=np.int64)
        ext_t1 = np.concatenate([none, none, t[:, 2:], t[:, 1:2]], axis=1)
        ext_t2 = np.concatenate([none, none, t[:, 2:], t[:, 0:1]], axis=1)
        marks = np.zeros((B.size, 2), dtype=np.int8)
        flag = np.zeros(B.size, dtype=bool)
        if d == 3:
            planar = (ma == mb) & (ma < 2)
            marks[:, 1] = planar & el["flagged"][B]  # new face marked at z p
            flag = planar & ~el["flagged"][B]
        sign = el["sign"][B]
        left = np.maximum(el["todo"][B] - 1, 0).astype(np.int16)
        first = {"cells": np.take_along_axis(ext, p1, 1), "sign": sign * sign1[ma], "marks": marks, "flagged": flag,
                 "gen": el["gen"][B] + 1, "origin": el["origin"][B], "tags": np.take_along_axis(ext_t1, p1, 1),
                 "todo": left}
        second = {**first, "cells": np.take_along_axis(ext, p2, 1), "sign": sign * sign2[mb],
                  "tags": np.take_along_axis(ext_t2, p2, 1)}
        new = n_el + np.arange(B.size)
        for name, a in el.items():
            if a.shape[0] < n_el + B.size:  # double at least: amortised O(1) per element
                a = np.concatenate([a[:n_el], np.empty((max(B.size, n_el),) + a.shape[1:], a.dtype)])
            a[B], a[new] = first[name], second[name]
            el[name] = a
        pending = np.concatenate([B[left > 0], new[left > 0]])

        # next round checks the children and the simplices that contain both
        # ends of an edge bisected in this round
        touched = np.zeros(points.shape[0], dtype=bool)
        touched[lo] = touched[hi] = True
        recheck = touched[el["cells"][:n_el]].sum(axis=1, dtype=np.uint8) >= 2
        recheck[B] = True
        check = np.concatenate([np.flatnonzero(recheck), new])
        n_el += B.size
    else:
        raise RuntimeError(f"bisection closure did not end within {max_rounds} rounds")

    el = {name: a[:n_el].copy() if a.shape[0] > n_el else a for name, a in el.items()}  # release the spare room
    cells, sign, tags = el["cells"], el["sign"], el["tags"]
    oriented = cells.copy()
    neg = sign < 0
    oriented[neg, :2] = oriented[neg, 1::-1]
    groups = _refined_groups(mesh, points, cells, tags, members)
    new_state = BisectionState(cells=cells, orientation=sign, marks=el["marks"], flagged=el["flagged"],
                               generation=el["gen"], node_parents=np.concatenate(parents))
    return Mesh(points=points, cells=oriented, groups=groups), new_state, el["origin"]


def prolong_p1(state: BisectionState, values: np.ndarray) -> np.ndarray:
    """Interpolate a P1 field given at the first ``len(values)`` nodes (a mesh
    before refinement) onto all nodes of ``state`` (the refined mesh): each new
    node takes the mean of the two ends of the edge it bisected, which is the
    value of the P1 field there. ``values`` is ``(n_old,)`` or ``(n_old, ...)``."""
    expect(state, BisectionState, "state", "the state ep.refine returned with the refined mesh")
    values = check_array("values", values)
    if values.ndim == 0:
        raise InputError("values", "expected one value (or row) per node of the mesh before refinement, got a scalar")
    n_old, n = values.shape[0], state.n_nodes
    par = state.node_parents
    if n_old > n or n_old < int(np.sum(par[:, 0] < 0)):
        raise InputError("values", f"{n_old} nodal values do not fit a mesh of this refinement history ({n} nodes)")
    out = np.empty((n,) + values.shape[1:], dtype=np.result_type(values.dtype, float))
    out[:n_old] = values
    i = n_old
    while i < n:  # blocks of nodes whose parents are all known (one per bisection round)
        late = np.flatnonzero(par[i:].max(axis=1) >= i)
        j = n if late.size == 0 else i + int(late[0])
        out[i:j] = 0.5 * (out[par[i:j, 0]] + out[par[i:j, 1]])
        i = j
    return out


# ----------------------------------------------------------------------------
# marking and quality
# ----------------------------------------------------------------------------


def dorfler_mark(indicators: np.ndarray, theta: float) -> np.ndarray:
    """Dörfler's bulk criterion: mark the largest indicators until their sum
    reaches ``theta`` times the total.

    The result is ``eta >= eta*`` with ``eta*`` the largest value such that
    ``sum(eta[eta >= eta*]) >= theta * sum(eta)``: the smallest set among
    those that contain every element at least as large as any marked one
    (equal indicators are marked together, so the set does not depend on the
    numbering). Monotone: a larger ``theta`` marks a superset, and no element
    is left unmarked while a smaller one is marked. Zero indicators are never
    marked; ``theta = 0`` marks nothing.
    """
    eta = check_array("indicators", indicators)
    if eta.ndim != 1:
        raise InputError("indicators", f"expected one indicator per element, got shape {eta.shape}")
    if not np.all(np.isfinite(eta)):
        raise InputError("indicators", f"{int(np.sum(~np.isfinite(eta)))} indicator(s) are NaN or infinite")
    if np.any(eta < 0):
        raise InputError("indicators", f"{int(np.sum(eta < 0))} indicator(s) are negative (min {eta.min():.3g})")
    theta = check_value("theta", theta, Spec(float, "", lo=0.0, hi=1.0))
    ordered = np.sort(eta)[::-1]
    cumulative = np.cumsum(ordered)
    target = theta * (cumulative[-1] if eta.size else 0.0)
    if target <= 0.0:
        return np.zeros(eta.size, dtype=bool)
    k = min(int(np.searchsorted(cumulative, target, side="left")), eta.size - 1)
    return eta >= ordered[k]


def shape_quality(mesh: Mesh) -> np.ndarray:
    """Inradius over longest edge of each simplex, divided by its value for the
    regular simplex, ``1/sqrt(2 d (d+1))``: 1 for equilateral, 0 for flat.
    The inradius is ``d |T| / (sum of the facet measures)``."""
    d = _check_mesh(mesh)
    X = mesh.points[mesh.cells]
    vol = np.abs(signed_volumes(mesh.points, mesh.cells))
    le = local_edges(d)
    longest = np.sqrt(np.max(np.sum((X[:, le[:, 0]] - X[:, le[:, 1]]) ** 2, axis=2), axis=1))
    boundary = sum(facet_measure(np.delete(X, i, axis=1)) for i in range(d + 1))
    inradius = d * vol / boundary
    return inradius / longest * np.sqrt(2.0 * d * (d + 1))
