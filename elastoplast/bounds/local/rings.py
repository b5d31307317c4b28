"""Ring patches of the local lower bound: the elements around an edge (3D) or a vertex (2D).

The entity (an edge in 3D, a vertex in 2D) has ``k`` elements around it; its *ring faces*
are the facets through it. A correction of the tractions on the ring faces changes only
the ring's elements (every other facet of a ring element is off the entity and keeps its
traction). Orient every ring face by the rotation about the entity (``n_rot``: the
edge vector times the face's third vertex in 3D, the edge rotated by +90 degrees in 2D):
each ring element lies between two ring faces, and its outward normal is ``+n_rot`` on
one and ``-n_rot`` on the other (simplices are convex). Writing ``tau_f`` for the
traction ``sigma n_rot`` of face f and ``R_f tau_f`` for its force and moment about a
common point of the entity, every element's balance reads ``R_f tau_f = R_f' tau_f'``:
the corrections that keep every ring element balanced are exactly

    tau_f = K_f alpha_f + G_f rho    (interior faces),    R_f u_f = rho    (faces on the boundary),

with ``K_f`` a basis of the self-balanced linear tractions of one face (3 in 3D: in-plane,
``S (x - x_g)`` with the torque-free 2 x 2 tensors ``S``; 1 in 2D: tangential, opposite at
the two ends) and ``G_f`` a right inverse of ``R_f`` (a uniform traction for the force,
a linear normal traction and a rotational one for the moment), both in closed form, and
``rho`` the ring's common resultant. A ring through the boundary has two boundary faces
whose free traction components (symmetry and clamped facets; none on free and Γ0 facets)
restrict ``rho``: a small null space per boundary ring (SVD, once). This module builds
the rings, their colours (no element holds two entities of one colour) and the bases;
:mod:`elastoplast.bounds.local.sweeps` sweeps them."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from elastoplast.bounds.local.equilibrate import Faces, segment_ranges

#: singular values of a boundary ring's scaled constraint rows below this (relative) span its corrections
NULL_RCOND = 1e-10
#: elements per batch of rings (bounds the dense temporaries, about 20 kB per element in 3D)
BATCH_ELEMENTS = 1 << 14


def local_entities(d: int) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (n_le, d-1), facets (n_le, 2))``: the local entities of a simplex (edges
    in 3D, vertices in 2D) and the two local facets through each (those opposite the other vertices)."""
    ents = list(combinations(range(d + 1), d - 1))
    fac = [[i for i in range(d + 1) if i not in e] for e in ents]
    return np.array(ents, dtype=np.int64), np.array(fac, dtype=np.int64)


@dataclass
class RingBatch:
    """Rings of one colour: ``ent (m,)``; their elements ``E (m, ke)`` (``valid``), each
    element's local entity ``le``, ring-face positions ``j (m, ke, 2)`` of its two facets
    through the entity (local facets ``lf (m, ke, 2)``), orientations ``o (m, ke, 2)``
    (outward normal = o n_rot); ``F (m, kf)`` the ring faces (-1 pad), ``s (m, kf)`` their
    sign (stored traction = s tau), ``end (m, kf)`` boundary-face index 0/1 or -1, and
    ``Nb (m, 2 d d + nr, nq)`` the boundary rings' (u_0, u_1, rho) bases (identity on rho
    for interior rings; a batch holds interior rings only or rings through the boundary
    only, :func:`ring_batches`, and an interior batch's ``Nb`` is one read-only broadcast array)."""

    ent: np.ndarray
    E: np.ndarray
    valid: np.ndarray
    le: np.ndarray
    lf: np.ndarray
    j: np.ndarray
    o: np.ndarray
    F: np.ndarray
    s: np.ndarray
    end: np.ndarray
    Nb: np.ndarray


@dataclass
class Rings:
    """The ring structure of a mesh: ``elem_ent (n, n_le)`` the entity of each local entity
    of each element (:func:`local_entities`), ``point (n_ent, d)`` the reference point of
    each entity (the edge's midpoint, the vertex), ``ell (n_ent,)`` its length scale (the
    edge's length; in 2D the longest mean edge of the elements around the vertex),
    ``colour (n_ent,)``."""

    elem_ent: np.ndarray
    point: np.ndarray
    ell: np.ndarray
    colour: np.ndarray
    n_ent: int


def mesh_rings(points: np.ndarray, cells: np.ndarray, seed: int = 0) -> Rings:
    n, d1 = cells.shape
    d = d1 - 1
    LV, _ = local_entities(d)
    if d == 3:
        a, b = cells[:, LV[:, 0]], cells[:, LV[:, 1]]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        keys = lo.astype(np.int64) * (points.shape[0] + 1) + hi
        uniq, elem_ent = np.unique(keys.ravel(), return_inverse=True)
        elem_ent = elem_ent.reshape(n, -1)
        ev = np.column_stack([uniq // (points.shape[0] + 1), uniq % (points.shape[0] + 1)])
        point = 0.5 * (points[ev[:, 0]] + points[ev[:, 1]])
        ell = np.linalg.norm(points[ev[:, 1]] - points[ev[:, 0]], axis=1)
        n_ent = uniq.size
    else:
        elem_ent = cells.copy()
        n_ent = points.shape[0]
        point = points
        el = np.linalg.norm(points[cells] - points[np.roll(cells, 1, axis=1)], axis=2).mean(axis=1)
        ell = np.zeros(n_ent)
        np.maximum.at(ell, cells.ravel(), np.repeat(el, d1))
    colour = entity_colours(elem_ent, n_ent, seed)
    return Rings(elem_ent, point, ell, colour, n_ent)


def entity_colours(elem_ent: np.ndarray, n_ent: int, seed: int = 0) -> np.ndarray:
    """Colours of the entities such that no element holds two of one colour (Jones–Plassmann:
    each round colours the uncoloured entities whose random priority is the largest
    uncoloured one in every element that holds them)."""
    flat = elem_ent.ravel()
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=n_ent)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = counts > 0
    prio = np.random.default_rng(seed).permutation(n_ent).astype(float) + 1.0
    colour = -np.ones(n_ent, dtype=np.int64)
    colour[~has] = -2
    k = 0
    while np.any(colour == -1):
        live = np.where(colour == -1, prio, 0.0)
        emax = live[elem_ent].max(axis=1)
        best = np.zeros(n_ent)
        best[has] = np.maximum.reduceat(np.repeat(emax, elem_ent.shape[1])[order], starts[has])
        pick = (colour == -1) & (live == best)
        colour[pick] = k
        k += 1
    colour[colour == -2] = -1
    return colour


def rotation_normals(points, ent_point_ids, face_nodes, d):
    """``n_rot (N, d)`` of faces ``face_nodes (N, d)`` about their entity (3D: edge ``(a, b)``
    ``ent_point_ids (N, 2)``, a < b; 2D: vertex ``(N, 1)``), unnormalised."""
    if d == 3:
        a, b = ent_point_ids[:, 0], ent_point_ids[:, 1]
        third = face_nodes.sum(axis=1) - a - b
        return np.cross(points[b] - points[a], points[third] - points[a])
    p = ent_point_ids[:, 0]
    other = face_nodes.sum(axis=1) - p
    v = points[other] - points[p]
    return np.column_stack([-v[:, 1], v[:, 0]])


def ring_batches(points, cells, grads, faces: Faces, rings: Rings, free: np.ndarray, active: np.ndarray | None = None,
                 max_elements: int = BATCH_ELEMENTS) -> list[RingBatch]:
    """The :class:`RingBatch` es of the active rings (``active (n_ent,)`` bool, default all), colour by colour."""
    n, d1 = cells.shape
    d = d1 - 1
    LV, LF = local_entities(d)
    n_le = LV.shape[0]
    flat = rings.elem_ent.ravel()
    inc_e = np.repeat(np.arange(n), n_le)
    inc_l = np.tile(np.arange(n_le), n)
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=rings.n_ent)
    starts = np.concatenate([[0], np.cumsum(counts)])
    use = rings.colour >= 0
    if active is not None:
        use &= active
    # the rings through the boundary apart: the others' (u_0, u_1, rho) basis is the same identity, one
    # broadcast array for a whole batch (it was 80% of the batches' memory, 3 kB per tetrahedron)
    on_boundary = np.zeros(rings.n_ent, dtype=bool)
    on_boundary[rings.elem_ent[(faces.face >= faces.n_interior)[:, LF].any(axis=2)]] = True
    out = []
    for c in range(int(rings.colour.max(initial=-1)) + 1):
        for where in (False, True):
            group = np.flatnonzero(use & (rings.colour == c) & (on_boundary == where))
            group = group[np.argsort(counts[group], kind="stable")]
            i0 = 0
            while i0 < group.size:
                ke = int(counts[group[min(group.size - 1, i0 + max(1, max_elements // 8))]])
                size = max(1, max_elements // max(ke, 1))
                ents = group[i0: i0 + size]
                i0 += size
                b = _batch(ents, points, cells, grads, faces, rings, free, order, counts, starts, inc_e, inc_l, LV, LF)
                if b is not None:
                    out.append(b)
    return out


def _batch(ents, points, cells, grads, faces, rings, free, order, counts, starts, inc_e, inc_l, LV, LF):
    d1 = cells.shape[1]
    d = d1 - 1
    m = ents.size
    ke = int(counts[ents].max())
    cnt = counts[ents]
    sel = order[np.repeat(starts[ents], cnt) + segment_ranges(cnt)]
    row, col = np.repeat(np.arange(m), cnt), segment_ranges(cnt)
    E = np.zeros((m, ke), dtype=np.int64)
    le = np.zeros((m, ke), dtype=np.int64)
    valid = np.zeros((m, ke), dtype=bool)
    E[row, col], le[row, col], valid[row, col] = inc_e[sel], inc_l[sel], True
    lf = LF[le]  # (m, ke, 2)
    gf = faces.face[E[:, :, None], lf]  # (m, ke, 2)
    Ftot = faces.nodes.shape[0]
    keys = np.where(valid[:, :, None], np.arange(m)[:, None, None] * Ftot + gf, -1)
    uk = np.unique(keys[keys >= 0])
    ring_of = uk // Ftot
    kcount = np.bincount(ring_of, minlength=m)
    kf = int(kcount.max())
    fstart = np.concatenate([[0], np.cumsum(kcount)[:-1]])
    Fm = -np.ones((m, kf), dtype=np.int64)
    Fm[ring_of, np.arange(uk.size) - fstart[ring_of]] = uk % Ftot
    pos = np.searchsorted(uk, np.where(keys >= 0, keys, uk[0]))
    j = np.where(valid[:, :, None], pos - fstart[:, None, None], 0)
    # orientations: outward normal of element e on local facet i is -grads[e, i]
    if d == 3:
        LVe = LV[le]
        ev = np.sort(cells[E[:, :, None], LVe], axis=2)  # (m, ke, 2)
    else:
        ev = cells[E, le][:, :, None]
    fn = faces.nodes[gf]  # (m, ke, 2, d)
    nrot = rotation_normals(points, np.repeat(ev, 2, axis=1).reshape(-1, ev.shape[2]), fn.reshape(-1, d), d)
    outward = -grads[E[:, :, None], lf].reshape(-1, d)
    o = np.sign(np.einsum("ni,ni->n", outward, nrot)).reshape(m, ke, 2) * valid[:, :, None]
    s = np.where(valid[:, :, None], o * faces.sign[E[:, :, None], lf], 0.0)
    sf = np.zeros((m, kf))
    sf[np.broadcast_to(np.arange(m)[:, None, None], j.shape)[valid], j[valid]] = s[valid]
    # boundary faces
    bnd = (Fm >= faces.n_interior)
    nb = bnd.sum(axis=1)
    ok = (nb == 0) | (nb == 2)
    end = -np.ones((m, kf), dtype=np.int64)
    bi = np.cumsum(bnd, axis=1) - 1
    end[bnd] = bi[bnd]
    Nb = boundary_bases(points, faces, rings, ents, Fm, end, sf, free, d)
    if not ok.all():
        keep = ok
        if not keep.any():
            return None
        E, valid, le, lf, j, o, Fm, sf, end, Nb, ents = (x[keep] for x in (E, valid, le, lf, j, o, Fm, sf, end, Nb, ents))
    return RingBatch(ents, E, valid, le, lf, j, o, Fm, sf, end, Nb)


def resultant_rows(X: np.ndarray, p: np.ndarray, ell: np.ndarray) -> np.ndarray:
    """``(N, nr, d d)``: force over ``ell^(d-1)`` and moment about ``p`` over ``ell^d`` of the
    linear traction with vertex values ``tau (d slots, d)`` on faces with vertices ``X (N, d, d)``."""
    N, d, _ = X.shape
    nr = d + (1 if d == 2 else 3)
    g = X.mean(axis=1)
    if d == 3:
        A = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
        w = A[:, None, None] / 12.0 * (3.0 * (g - p)[:, None, :] + (X - p[:, None, :]))  # (N, slot, 3)
    else:
        A = np.linalg.norm(X[:, 1] - X[:, 0], axis=1)
        w = A[:, None, None] / 6.0 * (2.0 * (g - p)[:, None, :] + (X - p[:, None, :]))
    R = np.zeros((N, nr, d, d))
    for jj in range(d):
        R[:, jj, :, jj] = (A / d)[:, None] / ell[:, None] ** (d - 1)
    sc = 1.0 / ell[:, None] ** d
    if d == 3:  # (w x tau)_k = eps_kij w_i tau_j
        for k, (i1, j1) in enumerate([(1, 2), (2, 0), (0, 1)]):
            R[:, 3 + k, :, j1] += w[:, :, i1] * sc
            R[:, 3 + k, :, i1] -= w[:, :, j1] * sc
    else:
        R[:, 2, :, 1] += w[:, :, 0] * sc
        R[:, 2, :, 0] -= w[:, :, 1] * sc
    return R.reshape(N, nr, d * d)


def face_bases(X: np.ndarray, p: np.ndarray, ell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(K (N, dd, na), G (N, dd, nr))``: the self-balanced tractions of each face and a right
    inverse of :func:`resultant_rows` (closed form, module docstring)."""
    N, d, _ = X.shape
    g = X.mean(axis=1)
    r = X - g[:, None, :]
    if d == 2:
        t = X[:, 1] - X[:, 0]
        L = np.linalg.norm(t, axis=1)
        e = t / L[:, None]
        nvec = np.column_stack([-e[:, 1], e[:, 0]])
        K = np.stack([e, -e], axis=1).reshape(N, 4, 1) / np.sqrt(2.0)
        G = np.zeros((N, 2, 2, 3))
        for c in range(3):
            F = np.zeros((N, 2))
            Mp = np.zeros(N)
            if c < 2:
                F[:, c] = ell
            else:
                Mp = ell ** 2
            gp = g - p
            Mg = Mp - (gp[:, 0] * F[:, 1] - gp[:, 1] * F[:, 0])
            cc = 12.0 * Mg / L ** 3
            phi = cc[:, None] * np.einsum("nbi,ni->nb", r, e)
            G[:, :, :, c] = (F / L[:, None])[:, None, :] + phi[:, :, None] * nvec[:, None, :]
        return K, G.reshape(N, 4, 3)
    nv = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    A = 0.5 * np.linalg.norm(nv, axis=1)
    n = nv / (2.0 * A)[:, None]
    e1 = X[:, 1] - X[:, 0]
    e1 = e1 / np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(n, e1)
    r1, r2 = np.einsum("nbi,ni->nb", r, e1), np.einsum("nbi,ni->nb", r, e2)
    I11, I12, I22 = (r1 * r1).sum(1), (r1 * r2).sum(1), (r2 * r2).sum(1)
    # kernel: tau_b = S r_b, S = [[s11, s12], [s21, s22]] in (e1, e2), torque-free: a . s = 0
    a = np.column_stack([-I12, -I22, I11, I12])
    k = np.argmax(np.abs(a), axis=1)
    v = a.copy()
    ak = a[np.arange(N), k]
    v[np.arange(N), k] += np.where(ak >= 0, 1.0, -1.0) * np.linalg.norm(a, axis=1)
    Hh = np.eye(4)[None] - 2.0 * v[:, :, None] * v[:, None, :] / np.einsum("ni,ni->n", v, v)[:, None, None]
    cols = np.array([[c for c in range(4) if c != kk] for kk in range(4)])[k]  # (N, 3)
    S = np.take_along_axis(Hh, cols[:, None, :], axis=2)  # (N, 4, 3)
    E1, E2 = e1[:, None, :], e2[:, None, :]
    K = (S[:, 0, None, None, :] * (E1 * r1[:, :, None])[..., None] + S[:, 1, None, None, :] * (E1 * r2[:, :, None])[..., None]
         + S[:, 2, None, None, :] * (E2 * r1[:, :, None])[..., None] + S[:, 3, None, None, :] * (E2 * r2[:, :, None])[..., None])
    K = K.reshape(N, 9, 3)
    K = K / np.linalg.norm(K, axis=1, keepdims=True)
    det = I11 * I22 - I12 ** 2
    sr2 = (r * r).sum(axis=(1, 2))
    G = np.zeros((N, 3, 3, 6))
    gp = g - p
    for c in range(6):
        F = np.zeros((N, 3))
        Mp = np.zeros((N, 3))
        if c < 3:
            F[:, c] = ell ** 2
        else:
            Mp[:, c - 3] = ell ** 3
        Mg = Mp - np.cross(gp, F)
        mn = np.einsum("ni,ni->n", Mg, n)
        mt = Mg - mn[:, None] * n
        vv = 12.0 / A[:, None] * np.cross(n, mt)
        v1, v2 = np.einsum("ni,ni->n", vv, e1), np.einsum("ni,ni->n", vv, e2)
        c1 = (I22 * v1 - I12 * v2) / det
        c2 = (-I12 * v1 + I11 * v2) / det
        phi = c1[:, None] * r1 + c2[:, None] * r2
        tors = (12.0 * mn / (A * sr2))[:, None, None] * np.cross(n[:, None, :], r)
        G[:, :, :, c] = (F / A[:, None])[:, None, :] + tors + phi[:, :, None] * n[:, None, :]
    return K, G.reshape(N, 9, 6)


def boundary_bases(points, faces: Faces, rings: Rings, ents, Fm, end, sf, free, d) -> np.ndarray:
    """``(m, 2 dd + nr, nq)``: for each ring of a batch, a basis of (u_0, u_1, rho) with
    ``R_b u_b = rho`` on its two boundary faces (their free components only); identity on
    rho for interior rings."""
    m = ents.size
    dd = d * d
    nr = d + (1 if d == 2 else 3)
    nbnd = (end >= 0).sum(axis=1)
    br = np.flatnonzero(nbnd == 2)
    if br.size == 0:  # one read-only array for all: identity on rho
        Nb = np.zeros((1, 2 * dd + nr, nr))
        Nb[0, 2 * dd:, :] = np.eye(nr)
        return np.broadcast_to(Nb, (m, 2 * dd + nr, nr))
    pos = np.argsort(np.where(end[br] >= 0, end[br], 99), axis=1)[:, :2]  # positions of ends 0, 1
    fb = np.take_along_axis(Fm[br], pos, axis=1)  # (mb, 2)
    X = points[faces.nodes[fb.ravel()]]
    p = np.repeat(rings.point[ents[br]], 2, axis=0)
    ell = np.repeat(rings.ell[ents[br]], 2)
    R = resultant_rows(X, p, ell).reshape(br.size, 2, nr, dd)
    fr = np.repeat(free[fb][:, :, None, :], d, axis=2).reshape(br.size, 2, dd)  # slot-major (slot, comp)
    nc = 2 * dd + nr
    C = np.zeros((br.size, 2 * nr + 2 * dd, nc))
    C[:, :nr, :dd] = R[:, 0]
    C[:, nr:2 * nr, dd:2 * dd] = R[:, 1]
    C[:, :nr, 2 * dd:] = -np.eye(nr)
    C[:, nr:2 * nr, 2 * dd:] = -np.eye(nr)
    idx = np.arange(2 * dd)
    C[:, 2 * nr + idx, idx] = ~fr.reshape(br.size, 2 * dd)
    _, sv, Vt = np.linalg.svd(C, full_matrices=True)
    svf = np.zeros((br.size, nc))
    svf[:, :sv.shape[1]] = sv
    live = svf <= NULL_RCOND * sv[:, :1]
    nq = int(max(nr, live.sum(axis=1).max(initial=0)))
    Z = np.swapaxes(Vt, 1, 2)[:, :, nc - nq:] * live[:, None, nc - nq:]
    Z[:, :2 * dd][~fr.reshape(br.size, 2 * dd)] = 0.0
    Nb = np.zeros((m, nc, nq))
    Nb[:, 2 * dd:, :nr] = np.eye(nr)
    Nb[br] = Z
    return Nb
