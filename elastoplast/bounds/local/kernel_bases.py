"""The geometric pieces of the compiled ring step (:mod:`elastoplast.bounds.local.kernel`): each
ring face's closed-form bases (:func:`~elastoplast.bounds.local.rings.face_bases`, and
:func:`~elastoplast.bounds.local.sweeps.ring_face_bases` of one ring) and the small dense solve of a
ring's Newton system, as compiled loops."""

from __future__ import annotations

import numpy as np
from numba import njit

#: the floating-point licences of the compiled loops: reassociation (so that the sums vectorise), contraction
#: into fused multiply-adds, no signed zeros; not the 'no infinities / no NaN' ones (the pressure cap uses inf)
FAST = {"reassoc", "contract", "nsz"}


@njit(cache=True, fastmath=FAST)
def solve_small(Hs, rhs):
    """``Hs^-1 rhs`` by Gaussian elimination with partial pivoting (``Hs``, ``rhs`` overwritten; the
    rings' systems are small: numba's LAPACK binding compiles far slower than this)."""
    n = rhs.shape[0]
    for c in range(n):
        piv = c
        for rr in range(c + 1, n):
            if abs(Hs[rr, c]) > abs(Hs[piv, c]):
                piv = rr
        if piv != c:
            for x in range(n):
                Hs[c, x], Hs[piv, x] = Hs[piv, x], Hs[c, x]
            rhs[c], rhs[piv] = rhs[piv], rhs[c]
        inv = 1.0 / Hs[c, c]
        for rr in range(c + 1, n):
            f = Hs[rr, c] * inv
            if f != 0.0:
                for x in range(c, n):
                    Hs[rr, x] -= f * Hs[c, x]
                rhs[rr] -= f * rhs[c]
    for c in range(n - 1, -1, -1):
        acc = rhs[c]
        for x in range(c + 1, n):
            acc -= Hs[c, x] * rhs[x]
        rhs[c] = acc / Hs[c, c]
    return rhs


@njit(cache=True, fastmath=FAST)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True, fastmath=FAST)
def _face_basis(X, p, ell, K, G):
    """:func:`~elastoplast.bounds.local.rings.face_bases` of one face ``X (d, d)`` about ``p``: ``K (d d, na)``,
    ``G (d d, nr)``."""
    d = X.shape[0]
    g = np.zeros(d)
    for b in range(d):
        for i in range(d):
            g[i] += X[b, i] / d
    r = np.empty((d, d))
    for b in range(d):
        for i in range(d):
            r[b, i] = X[b, i] - g[i]
    if d == 2:
        e = np.empty(2)
        L = np.sqrt((X[1, 0] - X[0, 0]) ** 2 + (X[1, 1] - X[0, 1]) ** 2)
        e[0], e[1] = (X[1, 0] - X[0, 0]) / L, (X[1, 1] - X[0, 1]) / L
        nvec0, nvec1 = -e[1], e[0]
        h = 1.0 / np.sqrt(2.0)
        K[0, 0], K[1, 0], K[2, 0], K[3, 0] = e[0] * h, e[1] * h, -e[0] * h, -e[1] * h
        for c in range(3):
            F0 = ell if c == 0 else 0.0
            F1 = ell if c == 1 else 0.0
            Mp = ell * ell if c == 2 else 0.0
            Mg = Mp - ((g[0] - p[0]) * F1 - (g[1] - p[1]) * F0)
            cc = 12.0 * Mg / L ** 3
            for b in range(2):
                phi = cc * (r[b, 0] * e[0] + r[b, 1] * e[1])
                G[b * 2 + 0, c] = F0 / L + phi * nvec0
                G[b * 2 + 1, c] = F1 / L + phi * nvec1
        return
    u = np.empty(3)
    v = np.empty(3)
    n = np.empty(3)
    for i in range(3):
        u[i] = X[1, i] - X[0, i]
        v[i] = X[2, i] - X[0, i]
    _cross(u, v, n)
    A = 0.5 * np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
    for i in range(3):
        n[i] /= 2.0 * A
    lu = np.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
    e1 = u / lu
    e2 = np.empty(3)
    _cross(n, e1, e2)
    r1 = np.empty(3)
    r2 = np.empty(3)
    for b in range(3):
        r1[b] = r[b, 0] * e1[0] + r[b, 1] * e1[1] + r[b, 2] * e1[2]
        r2[b] = r[b, 0] * e2[0] + r[b, 1] * e2[1] + r[b, 2] * e2[2]
    I11 = r1[0] * r1[0] + r1[1] * r1[1] + r1[2] * r1[2]
    I12 = r1[0] * r2[0] + r1[1] * r2[1] + r1[2] * r2[2]
    I22 = r2[0] * r2[0] + r2[1] * r2[1] + r2[2] * r2[2]
    # the torque-free 2 x 2 tensors: the orthogonal complement of a by a Householder reflection
    a = np.array([-I12, -I22, I11, I12])
    kk = 0
    for c in range(1, 4):
        if abs(a[c]) > abs(a[kk]):
            kk = c
    hv = a.copy()
    hv[kk] += (1.0 if a[kk] >= 0 else -1.0) * np.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2 + a[3] ** 2)
    vv2 = hv[0] ** 2 + hv[1] ** 2 + hv[2] ** 2 + hv[3] ** 2
    S = np.empty((4, 3))
    col = 0
    for c in range(4):
        if c == kk:
            continue
        for rr in range(4):
            S[rr, col] = (1.0 if rr == c else 0.0) - 2.0 * hv[rr] * hv[c] / vv2
        col += 1
    for c in range(3):
        nrm2 = 0.0
        for b in range(3):
            for i in range(3):
                val = (S[0, c] * e1[i] * r1[b] + S[1, c] * e1[i] * r2[b] + S[2, c] * e2[i] * r1[b]
                       + S[3, c] * e2[i] * r2[b])
                K[b * 3 + i, c] = val
                nrm2 += val * val
        nrm = np.sqrt(nrm2)
        for x in range(9):
            K[x, c] /= nrm
    det = I11 * I22 - I12 ** 2
    sr2 = 0.0
    for b in range(3):
        for i in range(3):
            sr2 += r[b, i] ** 2
    gp = g - p
    F = np.empty(3)
    Mp = np.empty(3)
    Mg = np.empty(3)
    w = np.empty(3)
    nr_ = np.empty(3)
    for c in range(6):
        for i in range(3):
            F[i] = ell ** 2 if c == i else 0.0
            Mp[i] = ell ** 3 if c == 3 + i else 0.0
        _cross(gp, F, w)
        for i in range(3):
            Mg[i] = Mp[i] - w[i]
        mn = Mg[0] * n[0] + Mg[1] * n[1] + Mg[2] * n[2]
        for i in range(3):
            w[i] = Mg[i] - mn * n[i]
        _cross(n, w, Mg)  # n x mt
        v1 = 12.0 / A * (Mg[0] * e1[0] + Mg[1] * e1[1] + Mg[2] * e1[2])
        v2 = 12.0 / A * (Mg[0] * e2[0] + Mg[1] * e2[1] + Mg[2] * e2[2])
        c1 = (I22 * v1 - I12 * v2) / det
        c2 = (-I12 * v1 + I11 * v2) / det
        for b in range(3):
            phi = c1 * r1[b] + c2 * r2[b]
            _cross(n, r[b], nr_)
            for i in range(3):
                G[b * 3 + i, c] = F[i] / A + 12.0 * mn / (A * sr2) * nr_[i] + phi * n[i]


@njit(cache=True, fastmath=FAST)
def ring_bases(ir, F, end, Nb, points, nodes, point, ell, ent, B):
    """:func:`~elastoplast.bounds.local.sweeps.ring_face_bases` of ring ``ir`` into ``B (kf, d d, na + nq)``."""
    kf = F.shape[1]
    d = points.shape[1]
    dd = d * d
    nq = Nb.shape[2]
    na = B.shape[2] - nq
    nr = d + (1 if d == 2 else 3)
    X = np.empty((d, d))
    K = np.empty((dd, na))
    G = np.empty((dd, nr))
    p = point[ent[ir]]
    for f in range(kf):
        for x in range(dd):
            for c in range(na + nq):
                B[f, x, c] = 0.0
        fid = F[ir, f]
        if fid < 0:
            continue
        if end[ir, f] >= 0:
            e = end[ir, f]
            for x in range(dd):
                for c in range(nq):
                    B[f, x, na + c] = Nb[ir, e * dd + x, c]
            continue
        for b in range(d):
            for i in range(d):
                X[b, i] = points[nodes[fid, b], i]
        _face_basis(X, p, ell[ent[ir]], K, G)
        for x in range(dd):
            for c in range(na):
                B[f, x, c] = K[x, c]
            for c in range(nq):
                acc = 0.0
                for j in range(nr):
                    acc += G[x, j] * Nb[ir, 2 * dd + j, c]
                B[f, x, na + c] = acc
