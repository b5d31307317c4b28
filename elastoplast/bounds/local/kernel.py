"""The ring sweep's Newton step compiled (numba): ring by ring, nothing batched in memory.

The step is written once, here, as compiled loops one ring at a time (a batched numpy form
over every element of a colour was bound by its ``(N, ...)`` temporaries' memory traffic,
and is gone): the ring faces' bases computed in place
(:mod:`elastoplast.bounds.local.kernel_bases`) and the element Hessian's elastic part from
the reference operators packed by symmetry (:func:`~elastoplast.bounds.local.sweeps.packed_hessian_operator`).
It releases the GIL, so :func:`~elastoplast.bounds.local.sweeps.compiled_ring_step` runs slices of
one colour in threads (the rings of a colour share no element and no facet: their writes
into ``t`` never meet). The descent's preconditioner takes the rings' Hessians from the numpy
:func:`~elastoplast.bounds.local.sweeps.ring_hessians`.

Notation as in :mod:`elastoplast.bounds.local.sweeps`: per element ``e`` of a ring, its two facets
through the entity (``lf``), their positions among the ring faces (``jpos``) and
orientations (``o``); ``B (kf, d d, na + nq)`` the ring faces' bases; the element's lift
``sig (s b, k)`` at its sub-element vertices from the outward vertex tractions, with the
double Piola map ``TP (k, m)``; ``J_e = w/2 sum_s sig_s (M x A) sig_s + w/(2H) sum_s
eta_s M eta_s``, ``eta = max(0, vm - sy)``. The first call compiles (about half a minute
on the two-core machine); numba caches the machine code beside the module, so later
processes load it."""

from __future__ import annotations

import numpy as np
from numba import njit

from elastoplast.bounds.local.kernel_bases import FAST, ring_bases, solve_small

SQRT_3_2 = np.sqrt(1.5)


@njit(cache=True, fastmath=FAST)
def _lift(e, t, face, slot, sign, Jinv, scale, Lfull, TP, base, out):
    """``out (d1 d1, k)``: the sub-vertex stresses of element ``e`` from the facet tractions ``t``."""
    d = Jinv.shape[1]
    d1 = d + 1
    k, mm = TP.shape[1], TP.shape[2]
    nte = d1 * d1 * d
    that = np.zeros(nte)
    for i in range(d1):
        f = face[e, i]
        c = sign[e, i] * scale[e, i]
        for a in range(d1):
            sl = slot[e, i, a]
            if sl < 0:
                continue
            for ii in range(d):
                acc = 0.0
                for jj in range(d):
                    acc += t[f, sl, jj] * Jinv[e, ii, jj]
                that[(i * d1 + a) * d + ii] = c * acc
    for sb in range(d1 * d1):
        for kk in range(k):
            out[sb, kk] = base[e, kk]
        for p in range(mm):
            acc = 0.0
            row = sb * mm + p
            for x in range(nte):
                acc += Lfull[row, x] * that[x]
            for kk in range(k):
                out[sb, kk] += acc * TP[e, kk, p]


@njit(cache=True, fastmath=FAST)
def _von_mises(sig, dev):
    """``vm`` of one Mandel stress ``sig (k,)``; its deviator into ``dev``."""
    mean = (sig[0] + sig[1] + sig[2]) / 3.0
    s2 = 0.0
    for kk in range(sig.shape[0]):
        dev[kk] = sig[kk] - mean if kk < 3 else sig[kk]
        s2 += dev[kk] * dev[kk]
    return SQRT_3_2 * np.sqrt(s2)


@njit(cache=True, fastmath=FAST)
def _energy(sig, w, A, M, sy, H):
    """``J_e`` of sub-vertex stresses ``sig (d1 d1, k)`` (sub volume ``w``): the compiled twin of
    :func:`elastoplast.bounds.local.energy.element_energy` (the one numpy J_e), kept because the
    ring step and the descent's energy call it per element inside compiled loops;
    ``tests/test_local_frame.py::test_field_energy_is_the_sum_of_the_element_energies`` holds the two to each other."""
    d1 = M.shape[0]
    k = sig.shape[1]
    dev = np.empty(k)
    As = np.empty((d1, k))
    eta = np.zeros(d1)
    el = 0.0
    for s in range(d1):
        for b in range(d1):
            for kk in range(k):
                acc = 0.0
                for ll in range(k):
                    acc += A[kk, ll] * sig[s * d1 + b, ll]
                As[b, kk] = acc
        for b in range(d1):
            for c in range(d1):
                acc = 0.0
                for kk in range(k):
                    acc += sig[s * d1 + b, kk] * As[c, kk]
                el += M[b, c] * acc
        if H > 0:
            for b in range(d1):
                eta[b] = max(_von_mises(sig[s * d1 + b], dev) - sy, 0.0)
            for b in range(d1):
                for c in range(d1):
                    el += M[b, c] * eta[b] * eta[c] / H
    return 0.5 * w * el


@njit(cache=True, fastmath=FAST)
def _stress_gradient(e, sq, w, A, M, sy, H, Dv, TP, gs, As, vm, eta, etaMs, nrm, dev, z):
    """The gradient of ``J_e`` in element ``e``'s sub-vertex stresses ``sq (d1 d1, k)``: ``gs = w (M x A)
    sq`` plus the plastic part ``w/H (eta M) n`` (``n = 1.5 dev sq / vm`` where ``eta > 0``: into ``nrm``),
    and ``z = TP^T gs`` per sub-vertex, the gradient in the in-plane reference values; fills ``vm``,
    ``eta``, ``etaMs = eta M``; True where some sub-vertex is plastic."""
    d1 = M.shape[0]
    k, mm = TP.shape[1], TP.shape[2]
    plastic = False
    for sb in range(d1 * d1):
        vm[sb] = _von_mises(sq[sb], dev) if H > 0 else 0.0
        eta[sb] = max(vm[sb] - sy, 0.0) if H > 0 else 0.0
        if eta[sb] > 0:
            plastic = True
            for kk in range(k):
                acc = 0.0
                for ll in range(k):
                    acc += Dv[kk, ll] * sq[sb, ll]
                nrm[sb, kk] = 1.5 * acc / max(vm[sb], 1e-300)
        else:
            for kk in range(k):
                nrm[sb, kk] = 0.0
    for sb in range(d1 * d1):
        for kk in range(k):
            acc = 0.0
            for ll in range(k):
                acc += A[kk, ll] * sq[sb, ll]
            As[sb, kk] = acc
    for s_ in range(d1):
        for b in range(d1):
            sb = s_ * d1 + b
            etaM = 0.0
            for c in range(d1):
                etaM += eta[s_ * d1 + c] * M[c, b]
            etaMs[sb] = etaM
            for kk in range(k):
                acc = 0.0
                for c in range(d1):
                    acc += M[b, c] * As[s_ * d1 + c, kk]
                gs[sb, kk] = w * acc + (w / H * etaM * nrm[sb, kk] if H > 0 else 0.0)
    for sb in range(d1 * d1):
        for p in range(mm):
            acc = 0.0
            for kk in range(k):
                acc += gs[sb, kk] * TP[e, kk, p]
            z[sb * mm + p] = acc
    return plastic


@njit(cache=True, fastmath=FAST, nogil=True)
def field_energy_kernel(lo, hi, t, face, slot, sign, Jinv, scale, Lfull, TP, base, volumes, A, M, sy, H, Dv,
                        gradient, J_el, g_el):
    """Elements ``lo`` to ``hi`` of the lifted field's J (:func:`~elastoplast.bounds.local.descent.field_energy`):
    ``J_el (n,)`` each element's ``J_e``, and, with ``gradient``, ``g_el (n, d1, d1, d)`` its gradient
    in the element's outward vertex tractions (the caller adds them into the facets)."""
    d = Jinv.shape[1]
    d1 = d + 1
    k, mm = TP.shape[1], TP.shape[2]
    nte = d1 * d1 * d
    sq = np.empty((d1 * d1, k))
    gs = np.empty((d1 * d1, k))
    As = np.empty((d1 * d1, k))
    vm = np.empty(d1 * d1)
    eta = np.empty(d1 * d1)
    etaMs = np.empty(d1 * d1)
    nrm = np.empty((d1 * d1, k))
    dev = np.empty(k)
    z = np.empty(d1 * d1 * mm)
    gt = np.empty(nte)
    for e in range(lo, hi):
        w = volumes[e] / d1
        _lift(e, t, face, slot, sign, Jinv, scale, Lfull, TP, base, sq)
        J_el[e] = _energy(sq, w, A, M, sy, H)
        if not gradient:
            continue
        _stress_gradient(e, sq, w, A, M, sy, H, Dv, TP, gs, As, vm, eta, etaMs, nrm, dev, z)
        for x in range(nte):
            gt[x] = 0.0
        for S_ in range(d1 * d1 * mm):
            zs = z[S_]
            for x in range(nte):
                gt[x] += zs * Lfull[S_, x]
        for i in range(d1):
            c = scale[e, i]
            for a in range(d1):
                for jj in range(d):
                    acc = 0.0
                    for ii in range(d):
                        acc += gt[(i * d1 + a) * d + ii] * Jinv[e, ii, jj]
                    g_el[e, i, a, jj] = c * acc


@njit(cache=True)
def add_element_gradients(g_el, face, slot, sign, g):
    """``g (F, d, d) +=`` each element's gradient in its outward vertex tractions, into its facets' slots."""
    n, d1 = face.shape
    d = g.shape[2]
    for e in range(n):
        for i in range(d1):
            f = face[e, i]
            for a in range(d1):
                sl = slot[e, i, a]
                if sl < 0:
                    continue
                for jj in range(d):
                    g[f, sl, jj] += sign[e, i] * g_el[e, i, a, jj]


@njit(cache=True, fastmath=FAST)
def _one_ring(ir, batch, geometry, field, material, operators, obstacle, control, gain):
    """Ring ``ir`` of :func:`ring_newton` (its arguments' groups unpacked here)."""
    E, valid, le, lf, jpos, o, F, s, end, Nb, na = batch
    points, nodes, point, ell, ent = geometry
    t, face, slot, sign, Jinv, scale, TP, base, volumes = field
    A, M, sy, H, Dv = material
    Lfull, Lsel, LselT, HQ, pairs, tri, AV = operators
    contact, psi = obstacle
    steps, ridge, lam_margin = control
    m_r, ke = E.shape
    kf = F.shape[1]
    d = Jinv.shape[1]
    d1 = d + 1
    k, mm = TP.shape[1], TP.shape[2]
    nS = d1 * d1 * mm
    nsel = Lsel.shape[2]
    nq = Nb.shape[2]
    nb = na + nq
    re = 2 * na + nq
    r = kf * na + nq
    dd = d * d
    npair = pairs.shape[0]
    ntri = tri.shape[0]
    B = np.empty((kf, d * d, nb))
    ring_bases(ir, F, end, Nb, points, nodes, point, ell, ent, B)
    gr = np.zeros(r)
    Hr = np.zeros((r, r))
    sig = np.zeros((ke, d1 * d1, k))
    dsig = np.zeros((ke, d1 * d1, k))
    Gh = np.zeros((ke, re, nsel))
    HG = np.zeros((re, nsel))
    cid = np.zeros((ke, re), dtype=np.int64)
    wq = np.zeros(ke)
    gs = np.zeros((d1 * d1, k))
    As = np.zeros((d1 * d1, k))
    z = np.zeros(nS)
    gsel = np.zeros(nsel)
    AT = np.zeros((k, mm))
    Qp = np.zeros(npair)
    Hh = np.zeros((nsel, nsel))
    vm = np.zeros(d1 * d1)
    eta = np.zeros(d1 * d1)
    etaMs = np.zeros(d1 * d1)
    nrm = np.zeros((d1 * d1, k))
    dev = np.zeros(k)
    J0 = 0.0
    for q in range(ke):
        if not valid[ir, q]:
            continue
        e = E[ir, q]
        v = le[ir, q]
        w = volumes[e] / d1
        wq[q] = w
        sq = sig[q]
        _lift(e, t, face, slot, sign, Jinv, scale, Lfull, TP, base, sq)
        J0 += _energy(sq, w, A, M, sy, H)
        plastic = _stress_gradient(e, sq, w, A, M, sy, H, Dv, TP, gs, As, vm, eta, etaMs, nrm, dev, z)
        # Hessian in the selected element traction dofs: the elastic part through HQ
        for kk in range(k):
            for p2 in range(mm):
                acc = 0.0
                for ll in range(k):
                    acc += A[kk, ll] * TP[e, ll, p2]
                AT[kk, p2] = acc
        for ip in range(npair):
            p, p2 = pairs[ip, 0], pairs[ip, 1]
            acc = 0.0
            for kk in range(k):
                acc += TP[e, kk, p] * AT[kk, p2]
            Qp[ip] = w * acc
        for ixy in range(ntri):
            acc = 0.0
            for ip in range(npair):
                acc += Qp[ip] * HQ[v, ixy, ip]
            Hh[tri[ixy, 0], tri[ixy, 1]] = acc
            Hh[tri[ixy, 1], tri[ixy, 0]] = acc
        if plastic:
            Dq = np.zeros((mm, mm))
            for p in range(mm):
                for p2 in range(mm):
                    acc = 0.0
                    for kk in range(k):
                        for ll in range(k):
                            acc += TP[e, kk, p] * Dv[kk, ll] * TP[e, ll, p2]
                    Dq[p, p2] = 1.5 * acc
            Ln = np.zeros((d1 * d1, nsel))
            for sb in range(d1 * d1):
                for p in range(mm):
                    acc = 0.0
                    for kk in range(k):
                        acc += nrm[sb, kk] * TP[e, kk, p]
                    for x in range(nsel):
                        Ln[sb, x] += acc * Lsel[v, sb * mm + p, x]
            DL = np.zeros((mm, nsel))
            MLn = np.zeros(nsel)
            for s_ in range(d1):
                for b in range(d1):
                    sb = s_ * d1 + b
                    cc = etaMs[sb] / max(vm[sb], 1e-300) * w / H if eta[sb] > 0 else 0.0
                    for x in range(nsel):  # (M Ln)[s, b]
                        acc = 0.0
                        for c in range(d1):
                            acc += M[b, c] * Ln[s_ * d1 + c, x]
                        MLn[x] = w / H * acc
                    for y in range(nsel):  # Gauss-Newton, and Newton's -c n n^T
                        ly = Ln[sb, y]
                        for x in range(nsel):
                            Hh[y, x] += ly * (MLn[x] - cc * Ln[sb, x])
                    if cc != 0.0:  # Newton's curvature: c_sb L_sb^T Dq L_sb
                        for p in range(mm):
                            for x in range(nsel):
                                DL[p, x] = 0.0
                            for p2 in range(mm):
                                dq = cc * Dq[p, p2]
                                for x in range(nsel):
                                    DL[p, x] += dq * Lsel[v, sb * mm + p2, x]
                        for p in range(mm):
                            for x in range(nsel):
                                lx = Lsel[v, sb * mm + p, x]
                                for y in range(nsel):
                                    Hh[x, y] += lx * DL[p, y]
        # the element's rows of the ring unknowns, transposed: GT (re, nsel)
        G = Gh[q]
        for ff in range(2):
            i = lf[ir, q, ff]
            jp = jpos[ir, q, ff]
            ofs = o[ir, q, ff] * scale[e, i]
            for ai in range(d):
                sl = slot[e, i, AV[i, ai]]
                for ii in range(d):
                    x = (ff * d + ai) * d + ii
                    for jj in range(d):
                        cj = ofs * Jinv[e, ii, jj]
                        for c in range(na):
                            G[ff * na + c, x] += cj * B[jp, sl * d + jj, c]
                        for c in range(nq):
                            G[2 * na + c, x] += cj * B[jp, sl * d + jj, na + c]
            for c in range(na):
                cid[q, ff * na + c] = jp * na + c
        for c in range(nq):
            cid[q, 2 * na + c] = kf * na + c
        for x in range(nsel):
            acc = 0.0
            for S_ in range(nS):
                acc += z[S_] * LselT[v, x, S_]
            gsel[x] = acc
        for c in range(re):
            acc = 0.0
            for x in range(nsel):
                acc += gsel[x] * G[c, x]
            gr[cid[q, c]] += acc
        for c in range(re):  # HG = G Hh (Hh symmetric)
            for x in range(nsel):
                HG[c, x] = 0.0
            for y in range(nsel):
                gy = G[c, y]
                for x in range(nsel):
                    HG[c, x] += gy * Hh[y, x]
        for c in range(re):
            for c2 in range(c, re):
                acc = 0.0
                for x in range(nsel):
                    acc += G[c, x] * HG[c2, x]
                Hr[cid[q, c], cid[q, c2]] += acc
                if c2 != c:
                    Hr[cid[q, c2], cid[q, c]] += acc
    # the obstacle term of the Γ0 faces (their pressure t[:, :, d-1] = s tau[:, d-1])
    gp = np.zeros(r)
    has_c = False
    for f in range(kf):
        fid = F[ir, f]
        if fid < 0 or not contact[fid]:
            continue
        has_c = True
        for c in range(nb):
            acc = 0.0
            for sl in range(d):
                acc += psi[fid, sl] * B[f, sl * d + d - 1, c]
            acc *= s[ir, f]
            if c < na:
                gp[f * na + c] += acc
            else:
                gp[kf * na + c - na] += acc
    for c in range(r):
        gr[c] += gp[c]
    # the Jacobi-scaled system with its ridge; unknowns without curvature do not move
    ds = np.ones(r)
    dead = np.zeros(r, dtype=np.bool_)
    for c in range(r):
        if Hr[c, c] > 0:
            ds[c] = 1.0 / np.sqrt(Hr[c, c])
        else:
            dead[c] = True
    Hs = np.empty((r, r))
    rhs = np.empty(r)
    for c in range(r):
        for c2 in range(r):
            Hs[c, c2] = Hr[c, c2] * ds[c] * ds[c2]
        Hs[c, c] += (1.0 if dead[c] else 0.0) + ridge
        rhs[c] = gr[c] * ds[c]
    yv = solve_small(Hs, rhs)
    y = np.empty(r)
    for c in range(r):
        y[c] = 0.0 if dead[c] else -ds[c] * yv[c]
    # the change of every sub-vertex stress and of every ring face per unit step
    dth = np.zeros(nsel)
    dS = np.zeros(nS)
    for q in range(ke):
        if not valid[ir, q]:
            continue
        e = E[ir, q]
        v = le[ir, q]
        for x in range(nsel):
            dth[x] = 0.0
        for c in range(re):
            yc = y[cid[q, c]]
            for x in range(nsel):
                dth[x] += Gh[q, c, x] * yc
        for S_ in range(nS):
            acc = 0.0
            for x in range(nsel):
                acc += Lsel[v, S_, x] * dth[x]
            dS[S_] = acc
        for sb in range(d1 * d1):
            for kk in range(k):
                acc = 0.0
                for p in range(mm):
                    acc += dS[sb * mm + p] * TP[e, kk, p]
                dsig[q, sb, kk] = acc
    dtau = np.zeros((kf, dd))
    for f in range(kf):
        for x in range(dd):
            acc = 0.0
            for c in range(na):
                acc += B[f, x, c] * y[f * na + c]
            for c in range(nq):
                acc += B[f, x, na + c] * y[kf * na + c]
            dtau[f, x] = acc
    cap = 1.0
    lin = 0.0
    if has_c:  # the pressure stays >= 0 at the vertices of the Γ0 faces
        lim = np.inf
        for f in range(kf):
            fid = F[ir, f]
            if fid < 0 or not contact[fid]:
                continue
            for sl in range(d):
                dl = s[ir, f] * dtau[f, sl * d + d - 1]
                if dl < 0:
                    lim = min(lim, max(t[fid, sl, d - 1], 0.0) / -dl)
        cap = min(1.0, (1.0 - lam_margin) * lim)
        for c in range(r):
            lin += gp[c] * y[c]
    best = 0.0
    gain[ir] = 0.0
    if cap > 0:
        trial = np.empty((d1 * d1, k))
        for a in steps:
            at = a * cap
            Jr = at * lin
            for q in range(ke):
                if not valid[ir, q]:
                    continue
                for sb in range(d1 * d1):
                    for kk in range(k):
                        trial[sb, kk] = sig[q, sb, kk] + at * dsig[q, sb, kk]
                Jr += _energy(trial, wq[q], A, M, sy, H)
            if Jr < J0:
                best = at
                gain[ir] = J0 - Jr
                break
    if best > 0:
        for f in range(kf):
            fid = F[ir, f]
            if fid < 0:
                continue
            for sl in range(d):
                for jj in range(d):
                    t[fid, sl, jj] += s[ir, f] * best * dtau[f, sl * d + jj]


@njit(cache=True, fastmath=FAST, nogil=True)
def ring_newton(lo, hi, batch, geometry, field, material, operators, obstacle, control, gain):
    """One Newton step of J on each ring, the first step length of ``steps`` that lowers ``J_ring``
    written into ``t``; ``gain (m,)`` receives each ring's decrease of J. Rings ``lo`` to ``hi`` only,
    without the GIL: the caller runs slices of one colour in threads (its rings share no element and
    no facet). The arguments in groups (tuples; notation in the module docstring):
    ``batch (E, valid, le, lf, jpos, o, F, s, end, Nb, na)`` the rings (a
    :class:`~elastoplast.bounds.local.rings.RingBatch` and ``na``, the face bases' width);
    ``geometry (points, nodes, point, ell, ent)`` what their face bases are built from;
    ``field (t, face, slot, sign, Jinv, scale, TP, base, volumes)`` the tractions (written) and
    what lifts them; ``material (A, M, sy, H, Dv)``; ``operators (Lfull, Lsel, LselT, HQ, pairs,
    tri, AV)`` the reference operators (:func:`~elastoplast.bounds.local.sweeps.packed_hessian_operator`);
    ``obstacle (contact, psi)``; ``control (steps, ridge, lam_margin)``. The Hessian it assembles
    per ring is the numpy :func:`~elastoplast.bounds.local.sweeps.ring_hessians`'."""
    for ir in range(lo, hi):
        _one_ring(ir, batch, geometry, field, material, operators, obstacle, control, gain)
