"""The exact lift of balanced face tractions into one element (docs/bounds.md, "the local lower bound").

One linear stress per simplex cannot carry every balanced set of linear face tractions.
The composite elements of Johnson and Mercier (a triangle split at its barycentre into
three) and of Johnson, Křížek and Mercier (a tetrahedron split at its barycentre into
four) can: on the split, symmetric stresses linear on each piece, divergence-free and
with continuous tractions across the inner facets, map one-to-one onto the linear face
tractions of the element that are in force and moment balance. The dimensions are
checked when the reference matrix is built (:func:`reference_lift`), not assumed.

The lift of an element is the reference lift composed with the double Piola map
``sigma = J Sigma J^T / |det J|``: it keeps symmetry, zero divergence, and maps the
traction per unit reference area ``Sigma n_hat`` to ``J`` times it, so that
``sigma n dS = J Sigma n_hat dS_hat``.

Sub-element ``i`` of element ``e`` is ``e`` with its vertex ``i`` replaced by the
barycentre: it carries the element's facet ``i`` (opposite vertex ``i``) and has the
orientation of ``e``; the split mesh keeps the mesh's nodes and appends one node per
element (:func:`split_mesh`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from math import factorial

import numpy as np

from elastoplast.fem.assembly import element_jacobians
from elastoplast.mesh.base import Mesh

#: Mandel positions of the in-plane components (plane strain: tau33 is not lifted)
IN_PLANE = {2: np.array([0, 1, 3]), 3: np.arange(6)}
#: (row, column) of each in-plane Mandel component
MANDEL_PAIRS = {2: [(0, 0), (1, 1), (0, 1)], 3: [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]}


def mandel_to_tensor(v: np.ndarray, dim: int) -> np.ndarray:
    """``(..., k_in) -> (..., d, d)`` for the in-plane Mandel components of :data:`IN_PLANE`."""
    out = np.zeros(v.shape[:-1] + (dim, dim))
    for c, (i, j) in enumerate(MANDEL_PAIRS[dim]):
        w = 1.0 if i == j else 1.0 / np.sqrt(2.0)
        out[..., i, j] = w * v[..., c]
        out[..., j, i] = w * v[..., c]
    return out


def tensor_to_mandel(t: np.ndarray, dim: int) -> np.ndarray:
    """Inverse of :func:`mandel_to_tensor` (symmetric part)."""
    out = np.empty(t.shape[:-2] + (len(MANDEL_PAIRS[dim]),))
    for c, (i, j) in enumerate(MANDEL_PAIRS[dim]):
        out[..., c] = t[..., i, j] if i == j else np.sqrt(2.0) * 0.5 * (t[..., i, j] + t[..., j, i])
    return out


def split_mesh(mesh: Mesh) -> Mesh:
    """The barycentric split: the mesh's nodes, then one barycentre per element; cells
    ``(n (d+1), d+1)``, sub-element ``e (d+1) + i`` being element e with vertex i
    replaced by its barycentre. The facet groups are unchanged (every boundary facet of
    the mesh is a facet of the split)."""
    n, d = mesh.n_elements, mesh.dim
    centres = mesh.points[mesh.cells].mean(axis=1)
    cells = np.repeat(mesh.cells[:, None, :], d + 1, axis=1)
    new = mesh.n_nodes + np.arange(n)
    idx = np.arange(d + 1)
    cells[:, idx, idx] = new[:, None]
    return Mesh(np.vstack([mesh.points, centres]), cells.reshape(-1, d + 1), dict(mesh.groups),
                dict(mesh.other_groups))


def _gradients(X: np.ndarray) -> np.ndarray:
    """Barycentric gradients ``(d+1, d)`` of the simplex with vertices ``X (d+1, d)``."""
    J = (X[1:] - X[0]).T
    Ginv = np.linalg.inv(J)  # rows: gradients of b_1..b_d
    return np.vstack([-Ginv.sum(axis=0), Ginv])


def _normal(X: np.ndarray, opposite: int, inside: np.ndarray) -> np.ndarray:
    """Unit normal of the facet of ``X`` opposite vertex ``opposite``, pointing away from ``inside``."""
    g = _gradients(X)[opposite]
    n = -g / np.linalg.norm(g)
    face = np.delete(X, opposite, axis=0)
    return n if np.dot(face[0] - inside, n) > 0 else -n


@dataclass(frozen=True)
class ReferenceLift:
    """The lift on the reference simplex ``(0, e_1, ..., e_d)``.

    ``matrix (d+1, d+1, m, d+1, d+1, d)`` maps reference tractions ``t_hat[i, a, :]``
    (per unit reference area, on facet i at vertex a != i; entries with a == i are
    ignored) to the Mandel in-plane vertex values ``Sigma[i, j, :]`` of sub-element i;
    ``homogeneous_dim`` is the dimension of the divergence-free, traction-continuous
    space, ``traction_rank`` that of its tractions, ``balanced_dim`` that of the
    balanced linear face tractions; the lift is exact iff the three agree.
    ``normals (d+1, d)`` the outward unit normals, ``areas (d+1,)`` the facet measures."""

    matrix: np.ndarray
    homogeneous_dim: int
    traction_rank: int
    balanced_dim: int
    normals: np.ndarray
    areas: np.ndarray


@lru_cache(maxsize=None)
def reference_lift(dim: int) -> ReferenceLift:
    """Build and check the composite element's lift (Johnson–Mercier in 2D,
    Johnson–Křížek–Mercier in 3D), by linear algebra on the reference simplex."""
    d = dim
    m = len(MANDEL_PAIRS[d])
    V = np.vstack([np.zeros(d), np.eye(d)])
    c = V.mean(axis=0)
    subs = []
    for i in range(d + 1):
        X = V.copy()
        X[i] = c
        subs.append(X)
    n_unk = (d + 1) * (d + 1) * m

    def col(i, j):
        return ((i * (d + 1) + j) * m) + np.arange(m)

    # traction operator: (Sigma n) from the Mandel in-plane vector, (d, m)
    def trac(n):
        E = np.eye(m)
        return np.stack([mandel_to_tensor(E[q], d) @ n for q in range(m)], axis=1)

    rows = []
    for i in range(d + 1):  # div Sigma_i = sum_j Sigma_ij g_ij
        G = _gradients(subs[i])
        R = np.zeros((d, n_unk))
        for j in range(d + 1):
            R[:, col(i, j)] += trac(G[j])
        rows.append(R)
    for i in range(d + 1):  # inner facets between sub i and sub l
        for l in range(i + 1, d + 1):
            n = _normal(subs[i], l, subs[i].mean(axis=0))
            for q in range(d + 1):  # facet nodes: the barycentre and original vertices other than i, l
                if q == l:
                    continue
                qi, ql = (i, l) if q == i else (q, q)  # the barycentre sits at position i in sub i, l in sub l
                R = np.zeros((d, n_unk))
                R[:, col(i, qi)] += trac(n)
                R[:, col(l, ql)] -= trac(n)
                rows.append(R)
    A = np.vstack(rows)
    normals = np.array([_normal(V, i, c) for i in range(d + 1)])
    areas = np.array([np.sqrt(d) if i == 0 else 1.0 for i in range(d + 1)]) / factorial(d - 1)
    T = np.zeros(((d + 1) * (d + 1) * d, n_unk))
    for i in range(d + 1):
        for a in range(d + 1):
            if a != i:
                r = (i * (d + 1) + a) * d
                T[r: r + d, col(i, a)] = trac(normals[i])
    _, s, Vt = np.linalg.svd(A)
    tol = 1e-10 * s[0]
    rank = int(np.sum(s > tol))
    N = Vt[rank:].T  # null space basis
    TN = T @ N
    sv = np.linalg.svd(TN, compute_uv=False)
    t_rank = int(np.sum(sv > 1e-10 * sv[0]))
    balanced = (d + 1) * d * d - (d + d * (d - 1) // 2)
    L = N @ np.linalg.pinv(TN, rcond=1e-10)
    return ReferenceLift(L.reshape((d + 1, d + 1, m, d + 1, d + 1, d)), N.shape[1], t_rank, balanced, normals, areas)


@dataclass(frozen=True)
class ElementMaps:
    """Per element: ``J (n, d, d)`` (columns ``x_i - x_0``), ``Jinv``, ``det = |det J|``,
    and ``facet_areas (n, d+1)`` (facet i opposite vertex i)."""

    J: np.ndarray
    Jinv: np.ndarray
    det: np.ndarray
    facet_areas: np.ndarray


def element_maps(points: np.ndarray, cells: np.ndarray) -> ElementMaps:
    J = element_jacobians(points, cells)
    Jinv = np.linalg.inv(J)
    det = np.abs(np.linalg.det(J))
    d = J.shape[1]
    # |f_i| = |T| d |grad b_i| with grad b_i the rows of Jinv (i >= 1) and minus their sum (i = 0)
    g = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)
    areas = det[:, None] / factorial(d) * d * np.linalg.norm(g, axis=2)
    return ElementMaps(J, Jinv, det, areas)


def balance_matrices(X: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``(n, nb, (d+1)(d+1)d)``: force and moment (about the centroid) of the outward vertex
    tractions ``t[i, a, j]`` (zero weight where a == i) of the simplices with vertices
    ``X (n, d+1, d)`` and facet measures ``areas (n, d+1)``; translation-invariant."""
    n, d1, d = X.shape
    X = X - X.mean(axis=1, keepdims=True)
    Mf = np.full((d1, d1), 1.0 / (d * (d + 1)))
    Mf[np.diag_indices(d1)] = 2.0 / (d * (d + 1))
    mask = 1.0 - np.eye(d1)  # (i, a)
    pairs = [(k, l) for k in range(d) for l in range(k + 1, d)]
    C = np.zeros((n, d + len(pairs), d1, d1, d))
    for j in range(d):
        C[:, j, :, :, j] = areas[:, :, None] / d * mask
    # int_f x_k t_l = |f| sum_{a,b in f} M_ab x_a,k t_b,l
    W = areas[:, :, None, None] * (mask[:, :, None] * mask[:, None, :] * Mf)[None]  # (n, i, a, b)
    xw = np.einsum("niab,nak->nibk", W, X)  # (n, i, b, k)
    for r, (k, l) in enumerate(pairs):
        C[:, d + r, :, :, l] += xw[..., k]
        C[:, d + r, :, :, k] -= xw[..., l]
    return C.reshape(n, d + len(pairs), -1)


def balanced_part(C: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``t (n, nte)`` projected element by element onto ``C t = 0`` (``C (n, nb, nte)``), in
    the Euclidean metric of the physical tractions (rows normalised, one small solve each)."""
    C = C / np.maximum(np.linalg.norm(C, axis=2, keepdims=True), np.finfo(float).tiny)
    G = np.matmul(C, np.swapaxes(C, 1, 2))
    y = np.linalg.solve(G, np.einsum("nrx,nx->nr", C, t)[..., None])[..., 0]
    return t - np.einsum("nrx,nr->nx", C, y)


def _reference_lift(maps: ElementMaps, sl: slice, traction: np.ndarray, Lm: np.ndarray, ref: ReferenceLift):
    """The double Piola map of the reference lift, on the elements ``sl``."""
    d = traction.shape[-1]
    scale = maps.facet_areas[sl] / ref.areas  # dS / dS_hat per facet
    t_hat = np.einsum("nij,nfaj->nfai", maps.Jinv[sl], traction) * scale[:, :, None, None]
    Sig = (t_hat.reshape(t_hat.shape[0], -1) @ Lm.T).reshape(-1, d + 1, d + 1, len(MANDEL_PAIRS[d]))
    S = mandel_to_tensor(Sig, d)
    J = maps.J[sl]
    return np.einsum("nij,nsajk,nlk->nsail", J, S, J) / maps.det[sl, None, None, None, None]


def lift(maps: ElementMaps, traction: np.ndarray, chunk: int = 1 << 12) -> np.ndarray:
    """Vertex values ``(n, d+1 sub-elements, d+1 vertices, d, d)`` of the stress tensor
    that carries the physical vertex tractions ``traction (n, d+1 facets, d+1 vertices,
    d)`` (outward, per unit area; entries with vertex == facet ignored), exactly when
    they are balanced.

    The reference lift is a least-squares map in the metric of the *reference*
    tractions: on an element of condition number kappa (of J), the share of an input's
    force and moment imbalance that it leaves on the facets is amplified by up to about
    kappa^1.5 in the physical tractions (measured: 2 at kappa < 3, 1.3e4 at kappa 100..150).
    Tractions balanced to round-off (1e-16 relative) then come back with facet errors of
    1e-12 on a graded mesh. So the lift is refined once: the residual ``traction - sigma n``
    on the element's facets (small) is projected onto the balanced tractions in the
    physical metric (:func:`balanced_part`) and lifted again. What is left on the facets
    is the input's own imbalance in the physical metric (its round-off) plus the
    round-off of the correction, whatever kappa."""
    n, d = traction.shape[0], traction.shape[-1]
    d1 = d + 1
    ref = reference_lift(d)
    Lm = ref.matrix.reshape(-1, d1 * d1 * d)
    offdiag = (1.0 - np.eye(d1))[None, :, :, None]
    out = np.empty((n, d1, d1, d, d))
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        t = traction[sl] * offdiag
        sig = _reference_lift(maps, sl, t, Lm, ref)
        Jinv = maps.Jinv[sl]
        g = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)  # barycentric gradients
        nrm = -g / np.linalg.norm(g, axis=2, keepdims=True)  # outward unit normals (n, facet, d)
        X = np.concatenate([np.zeros((Jinv.shape[0], 1, d)), np.swapaxes(maps.J[sl], 1, 2)], axis=1)
        C = balance_matrices(X, maps.facet_areas[sl])
        r = (t - np.einsum("niajk,nik->niaj", sig, nrm) * offdiag).reshape(t.shape[0], -1)
        out[sl] = sig + _reference_lift(maps, sl, balanced_part(C, r).reshape(t.shape), Lm, ref)
    return out
