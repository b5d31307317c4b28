"""Equilibrated face tractions from a P1 solution, vertex star by vertex star (docs/bounds.md).

Ladevèze's element equilibration (EET): for an element stress ``sigma`` (constant per
element) in exact nodal balance with the boundary loads, look for linear tractions on
every facet, equal and opposite on its two sides, such that for every element T and
every vertex a of T (b_a its hat function)

    sum over the facets f of T containing a of  int_f t_{T,f} b_a  =  |T| sigma_T grad b_a.

The unknowns are the facet moments ``int_f t b_a`` (a d-vector per facet and facet
vertex); the rows and unknowns of one vertex a involve no other vertex, so the problem
splits into one small system per vertex star. Summing the rows over the vertices of T
gives the force and moment balance of T's facet tractions. The systems are
under-determined; each is closed by the weighted least-squares distance to the moments
of the averaged element traction. A star's system is solvable exactly when the nodal
balance holds at its vertex (a property of the P1 solution, to its solver's round-off).

Boundary facets: free facets carry no traction, Γ0 facets a prescribed normal traction,
symmetry facets none in the components that are not fixed; clamped components are
unknowns. Everything is batched: stars are grouped by their number of elements and
solved as stacks of small dense systems."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastoplast.bounds.static import mass_matrix
from elastoplast.mesh.topology import FacetTopology

#: relative cut-off of the pseudo-inverse of each star's Gram matrix (its kernel is the
#: constant vector for stars without unknown boundary moments)
STAR_RCOND = 1e-12
#: stars solved per batch (bounds the dense temporaries). Default 3D problem at 98,304
#: tetrahedra: 16,384 stars per batch 4.9 s and 557 MB above the start, 4,096 3.8 s and
#: 130 MB, 1,024 3.6 s and 110 MB (smaller batches stay in cache)
STAR_CHUNK = 1 << 11


@dataclass(frozen=True)
class Faces:
    """All facets of a mesh, interior ones first, then the boundary facets in the order of
    the :class:`FacetTopology`.

    ``nodes (F, d)`` sorted; ``measure (F,)``; ``n_interior``; per element ``face (n,
    d+1)`` the facet opposite each local vertex, ``sign (n, d+1)`` +1 where the element
    is the facet's first side (the facet traction is its outward traction), -1 else;
    ``slot (n, d+1, d+1)`` the position in ``nodes[face]`` of each local vertex (-1 on
    the diagonal); ``unknown (F, d)`` the traction components not prescribed (interior:
    all; boundary: the fixed displacement components)."""

    nodes: np.ndarray
    measure: np.ndarray
    n_interior: int
    face: np.ndarray
    sign: np.ndarray
    slot: np.ndarray
    unknown: np.ndarray


def mesh_faces(cells: np.ndarray, topo: FacetTopology, facet_areas: np.ndarray) -> Faces:
    """:class:`Faces` from the topology; ``facet_areas (n, d+1)`` the element facet measures."""
    n, d1 = cells.shape
    d = d1 - 1
    IE, IL = topo.interior_elements, topo.interior_local
    BE, BL = topo.boundary_elements, topo.boundary_local
    n_if = IE.shape[0]
    nodes = np.vstack([topo.interior_nodes, topo.boundary_nodes])
    face = np.empty((n, d1), dtype=np.int64)
    sign = np.empty((n, d1))
    face[IE[:, 0], IL[:, 0]] = np.arange(n_if)
    face[IE[:, 1], IL[:, 1]] = np.arange(n_if)
    sign[IE[:, 0], IL[:, 0]] = 1.0
    sign[IE[:, 1], IL[:, 1]] = -1.0
    face[BE, BL] = n_if + np.arange(BE.size)
    sign[BE, BL] = 1.0
    measure = np.empty(nodes.shape[0])
    measure[:n_if] = facet_areas[IE[:, 0], IL[:, 0]]
    measure[n_if:] = facet_areas[BE, BL]
    fn = nodes[face]  # (n, d+1, d)
    slot = np.argmax(fn[:, :, None, :] == cells[:, None, :, None], axis=3)  # (n, facet, vertex)
    idx = np.arange(d1)
    slot[:, idx, idx] = -1
    unknown = np.vstack([np.ones((n_if, d), dtype=bool), topo.fixed])
    return Faces(nodes, measure, n_if, face, sign, slot, unknown)


def element_nodal_forces(sigma: np.ndarray, volumes: np.ndarray, grads: np.ndarray) -> np.ndarray:
    """``Q (n, d+1, d) = |T| sigma_T grad b_a`` for stress tensors ``sigma (n, d, d)``."""
    return volumes[:, None, None] * np.einsum("nij,naj->nai", sigma, grads)


def average_moments(faces: Faces, sigma: np.ndarray, normals: np.ndarray, cells_n: int) -> np.ndarray:
    """Moments ``(F, d slots, d)`` of the averaged element traction, ``|f|/d {sigma} n``
    (n the facet's first side's outward normal; boundary facets: that element's traction)."""
    n, d1 = faces.face.shape
    d = d1 - 1
    F = faces.nodes.shape[0]
    acc = np.zeros((F, d))
    cnt = np.zeros(F)
    e = np.repeat(np.arange(n), d1)
    i = np.tile(np.arange(d1), n)
    f = faces.face.ravel()
    s = faces.sign.ravel()
    # the first side's outward normal is sign * (this side's outward normal)
    t = np.einsum("mij,mj->mi", sigma[e], normals[e, i] * s[:, None])
    np.add.at(acc, f, t)
    np.add.at(cnt, f, 1.0)
    tbar = acc / cnt[:, None]
    return np.repeat((faces.measure / d)[:, None, None] * tbar[:, None, :], d, axis=1)


@dataclass(frozen=True)
class StarSolution:
    """The facet moments ``(F, d slots, d)`` and the largest relative row residual of the
    star systems (the nodal imbalance of the input, to round-off)."""

    moments: np.ndarray
    residual: float


def star_moments(cells: np.ndarray, faces: Faces, Q: np.ndarray, target: np.ndarray, known: np.ndarray) -> StarSolution:
    """Solve every vertex star's system (module docstring).

    ``Q (n, d+1, d)`` the right-hand sides, ``target (F, d, d)`` the moments the
    least-squares closure stays near (weights ``1/|f|``), ``known (F, d, d)`` the
    prescribed moments (used where ``faces.unknown`` is False)."""
    n, d1 = cells.shape
    d = d1 - 1
    F = faces.nodes.shape[0]
    n_nodes = int(cells.max()) + 1
    # equations (e, a) and unknowns (f, s), each owned by one node
    eq_node = cells.ravel()
    unk_node = faces.nodes.ravel()
    eq_order = np.argsort(eq_node, kind="stable")
    unk_order = np.argsort(unk_node, kind="stable")
    eq_count = np.bincount(eq_node, minlength=n_nodes)
    unk_count = np.bincount(unk_node, minlength=n_nodes)
    eq_start = np.concatenate([[0], np.cumsum(eq_count)])
    unk_start = np.concatenate([[0], np.cumsum(unk_count)])
    eq_loc = np.empty(eq_node.size, dtype=np.int64)
    eq_loc[eq_order] = np.arange(eq_node.size) - eq_start[eq_node[eq_order]]
    unk_loc = np.empty(unk_node.size, dtype=np.int64)
    unk_loc[unk_order] = np.arange(unk_node.size) - unk_start[unk_node[unk_order]]

    # entries: equation (e, a), facet i != a, unknown face(e, i) * d + slot(e, i, a)
    e, i, a = np.nonzero(faces.slot >= 0)
    E = e * d1 + a
    U = faces.face[e, i] * d + faces.slot[e, i, a]
    val = faces.sign[e, i]
    node = eq_node[E]

    moments = np.where(faces.unknown[:, None, :], target, known).copy()  # (F, d, d)
    weight = np.repeat(faces.measure, d)  # 1 / weight of each unknown's moment
    free = np.repeat(faces.unknown, d, axis=0)  # (U, component)
    bk = moments.reshape(F * d, d)
    rhs = Q.reshape(n * d1, d)
    worst = 0.0
    scale = max(np.abs(Q).max(initial=0.0), np.finfo(float).tiny)

    # group the nodes by star size; within a group, batch in chunks
    sizes = eq_count
    entry_order = np.argsort(node, kind="stable")
    entry_start = np.concatenate([[0], np.cumsum(np.bincount(node, minlength=n_nodes))])
    for ne in np.unique(sizes[sizes > 0]):
        group = np.flatnonzero(sizes == ne)
        for c0 in range(0, group.size, STAR_CHUNK):
            nodes_c = group[c0: c0 + STAR_CHUNK]
            m = nodes_c.size
            nf = int(unk_count[nodes_c].max())
            pos = np.full(n_nodes, -1, dtype=np.int64)
            pos[nodes_c] = np.arange(m)
            # entries of these nodes
            lens = entry_start[nodes_c + 1] - entry_start[nodes_c]
            sel = entry_order[np.repeat(entry_start[nodes_c], lens) + segment_ranges(lens)]
            S = np.zeros((m, ne, nf))
            S[pos[node[sel]], eq_loc[E[sel]], unk_loc[U[sel]]] = val[sel]
            # unknown ids of each local column, equation ids of each local row
            col_id = np.full((m, nf), -1, dtype=np.int64)
            ul = unk_count[nodes_c]
            uidx = unk_order[np.repeat(unk_start[nodes_c], ul) + segment_ranges(ul)]
            col_id[np.repeat(np.arange(m), ul), unk_loc[uidx]] = uidx
            row_id = eq_order[(eq_start[nodes_c][:, None] + np.arange(ne)[None, :])]
            valid = col_id >= 0
            cid = np.where(valid, col_id, 0)
            for j in range(d):
                fr = free[cid, j] & valid  # (m, nf)
                b0 = bk[cid, j] * valid
                r = rhs[row_id, j] - np.einsum("mef,mf->me", S, b0)
                w = np.where(fr, weight[cid], 0.0)
                K = np.einsum("mef,mf,mgf->meg", S, w, S)
                x = np.einsum("meg,mg->me", np.linalg.pinv(K, rcond=STAR_RCOND, hermitian=True), r)
                bsol = b0 + w * np.einsum("mef,me->mf", S, x)
                res = r - np.einsum("mef,mf->me", S, bsol - b0)
                worst = max(worst, float(np.abs(res).max(initial=0.0)) / scale)
                upd = fr
                bk[cid[upd], j] = bsol[upd]
    return StarSolution(bk.reshape(F, d, d), worst)


def segment_ranges(lengths: np.ndarray) -> np.ndarray:
    """``concatenate([arange(l) for l in lengths])`` without a loop."""
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(total) - starts


def facet_tractions(faces: Faces, moments: np.ndarray) -> np.ndarray:
    """Vertex values ``(F, d, d)`` of the linear facet tractions with the given moments
    (``t = M^-1 b / |f|``, M the facet's P1 mass matrix over its measure)."""
    d = moments.shape[1]
    Minv = np.linalg.inv(mass_matrix(d - 1))
    return np.einsum("st,ftj->fsj", Minv, moments) / faces.measure[:, None, None]


def element_tractions(faces: Faces, t: np.ndarray, elements=slice(None)) -> np.ndarray:
    """Outward tractions ``(n, d+1 facets, d+1 vertices, d)`` of each element (or of
    ``elements``: indices or a slice; zero where vertex == facet) from the facet tractions ``t (F, d, d)``."""
    slot = faces.slot[elements]
    out = t[faces.face[elements][:, :, None], np.where(slot >= 0, slot, 0)] * faces.sign[elements][:, :, None, None]
    out[slot < 0] = 0.0
    return out
