"""Ring sweeps of the local lower bound: complementary-energy minimisation on edge patches
(3D) and vertex stars (2D) that keeps the field exactly admissible (docs/bounds.md).

On a ring (:mod:`elastoplast.bounds.local.rings`) the self-equilibrated corrections are
``tau_f = K_f alpha_f + W_f q`` in closed form. Each ring solves

    minimise  J_ring(t + B y)   over y = (alpha, q)

by one Newton step (exact for the elastic part; for the plastic part ``int eta^2 / 2H`` with
``eta = max(0, vm - sigma_y)`` at the sub-element vertices, the Gauss–Newton term plus the
curvature of ``vm`` where ``eta > 0``), kept with the first step length of :data:`STEPS`
that lowers J_ring. On Γ0 faces the pressure is a ring unknown: ``int lam = F`` is kept
(a ring is self-equilibrated: its boundary faces' net force is zero), ``lam >= 0`` by
capping the step, and J_ring gains the obstacle term ``sum q lam``. Rings of one colour
share no element and are solved as one batch; after the first sweep only the rings next
to a ring that moved are visited (:data:`ACTIVE_SHARE`). Nothing per element is stored
between batches: an element's Hessian in the tractions of its two faces through the
entity is assembled on the fly from fixed reference matrices (the composite element's
lift in reference tractions, :func:`~elastoplast.bounds.local.state.reference_operators`) combined with the element's
``(T P)^T A (T P)`` (P the double Piola map of the lift), one matrix product per
local-entity class."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import fields
from functools import lru_cache

import numpy as np

from elastoplast.bounds.local.equilibrate import Faces, element_tractions
from elastoplast.bounds.local.lift import MANDEL_PAIRS, ElementMaps, reference_lift
from elastoplast.bounds.local.rings import RingBatch, face_bases
from elastoplast.bounds.local.state import SweepState, reference_operators
from elastoplast.fem.material import von_mises
from elastoplast.limits import blocks

#: step lengths tried per ring (the first that lowers J_ring is kept)
STEPS = (1.0, 0.5, 0.25)
#: relative ridge of the Jacobi-scaled ring Hessian
RIDGE = 1e-12
#: a step that lowers a pressure stops this share short of zero (so round-off cannot make it negative)
LAM_MARGIN = 1e-9
#: per dimension: a ring is swept again when a ring sharing one of its elements lowered J by
#: more than this share of the mean gain per ring of the last sweep. Measured (default 3D
#: problem, 12,288 tetrahedra, 32 sweeps): 0.05 visits 312,003 rings in 72 s for a gap 1.48
#: times the global program's, 0.3 161k rings, 40 s, 1.49; 1.0 92k rings, 25 s, 1.52 (64
#: sweeps: 34 s, 1.45; 128: 83 s, 1.38; a share of 3 stops after 21k rings at 2.75). In 2D
#: the larger share stops the star sweeps early and leaves the work to the slower descent
#: (cylinder, 25,600 triangles, 64 sweeps then the descent: 0.05 17 s, 1.03; 1.0 34 s, 1.06)
ACTIVE_SHARE = {2: 0.05, 3: 1.0}
#: rings per slice of the compiled ring step at least, and slices per thread at most
#: (:func:`in_slices`): after the first sweep a colour holds few active rings (at 12,288
#: tetrahedra 38 a call on average), and rings in plastic zones cost more than the others
RING_SLICE = 8
RING_SLICES_PER_THREAD = 4
#: threads of the compiled ring step (:func:`compiled_ring_step`): the rings of one colour are cut in this many slices
KERNEL_THREADS = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def ring_sweep(points, cells, maps: ElementMaps, faces: Faces, rings, t: np.ndarray, volumes: np.ndarray,
               state: SweepState, batches: list[RingBatch], n_sweeps: int, progress=None) -> np.ndarray:
    """At most ``n_sweeps`` sweeps over the ring ``batches`` (after the first, only the rings
    next to a ring that moved, :data:`ACTIVE_SHARE`); returns the new facet tractions ``(F, d, d)``.
    ``state`` is :func:`~elastoplast.bounds.local.state.sweep_state`'s: its ``contact (F,)`` marks the Γ0 facets, whose pressure
    ``t[f, :, d-1] >= 0`` the rings may move when it is among the free components of the
    batches, and its ``psi (F, d)`` their obstacle weights ``q`` at the vertices (J gains
    ``sum q lam``); ``progress(i)`` is called after sweep i."""
    t = t.copy()
    active = np.ones(rings.n_ent, dtype=bool)
    for i in range(n_sweeps):
        gain = np.zeros(rings.n_ent)
        for b in batches:
            keep = active[b.ent]
            if keep.all():
                gain[b.ent] = compiled_ring_step(b, points, maps, faces, rings, t, volumes, state)
            elif keep.any():
                sub = subset(b, keep)
                gain[sub.ent] = compiled_ring_step(sub, points, maps, faces, rings, t, volumes, state)
        if progress is not None:
            progress(i + 1)
        # next sweep: the rings that share an element with a ring whose gain was not negligible
        done = int(active.sum())
        moved = gain > ACTIVE_SHARE[cells.shape[1] - 1] * gain.sum() / max(done, 1)
        if not moved.any():
            break
        active = np.zeros(rings.n_ent, dtype=bool)
        active[rings.elem_ent[moved[rings.elem_ent].any(axis=1)].ravel()] = True
    return t


def subset(b: RingBatch, keep) -> RingBatch:
    """The rings ``keep`` (bool, or a slice: then views) of a batch."""
    return RingBatch(*(getattr(b, f.name)[keep] for f in fields(RingBatch)))


def ring_face_bases(b: RingBatch, points, faces: Faces, rings, d: int) -> np.ndarray:
    """``(m, kf, d d, na + nq)``: the correction of each ring face's rotational traction per
    ring unknown (its own ``alpha`` then the ring's ``q``)."""
    m, kf = b.F.shape
    dd = d * d
    nq = b.Nb.shape[2]
    ok = b.F >= 0
    Fs = np.where(ok, b.F, 0)
    X = points[faces.nodes[Fs.ravel()]]
    p = np.repeat(rings.point[b.ent], kf, axis=0)
    ell = np.repeat(rings.ell[b.ent], kf)
    K, G = face_bases(X, p, ell)
    na = K.shape[2]
    K, G = K.reshape(m, kf, dd, na), G.reshape(m, kf, dd, -1)
    interior = ok & (b.end < 0)
    B = np.zeros((m, kf, dd, na + nq))
    B[..., :na] = K * interior[:, :, None, None]
    B[..., na:] = np.matmul(G, b.Nb[:, None, 2 * dd:, :]) * interior[:, :, None, None]
    for e in (0, 1):
        at = b.end == e
        B[..., na:] += np.where(at[:, :, None, None], b.Nb[:, None, e * dd:(e + 1) * dd, :], 0.0)
    return B


def ring_hessians(b: RingBatch, points, maps: ElementMaps, faces: Faces, rings, t: np.ndarray, volumes,
                  state: SweepState) -> np.ndarray:
    """``Hr (m, r, r)``: the Hessian of J on each ring of the batch in its unknowns (its faces'
    ``alpha``, then its ``q``) at the tractions ``t`` (what :class:`~elastoplast.bounds.local.descent.RingPreconditioner`
    inverts). The compiled step (:func:`compiled_ring_step`) assembles the same matrix ring by
    ring and takes the Newton step with it; ``tests/test_local_edges.py`` checks that they agree."""
    T, M, H = state.T, state.M, state.H
    _, sel, Lsel, HQ, HD, AV = state.ops
    m_r, ke = b.E.shape
    kf = b.F.shape[1]
    d = maps.J.shape[1]
    d1 = d + 1
    k = T.shape[0]
    mm = len(MANDEL_PAIRS[d])
    nsel = sel.shape[1]
    B = ring_face_bases(b, points, faces, rings, d)
    na = B.shape[3] - b.Nb.shape[2]
    nq = b.Nb.shape[2]
    r = kf * na + nq
    flat = b.E.ravel()
    N = flat.size
    le = b.le.ravel()
    valid = b.valid.ravel()
    ring = np.repeat(np.arange(m_r), ke)
    w = volumes[flat] / d1 * valid
    # element traction dofs of the two facets: face position, slot
    lf = b.lf.reshape(N, 2)
    jpos = b.j.reshape(N, 2)
    o = b.o.reshape(N, 2)
    verts = AV[lf]  # (N, 2, d)
    slot = faces.slot[flat[:, None, None], lf[:, :, None], verts]  # (N, 2, d)
    rows = B.reshape(m_r, kf, d, d, -1)[ring[:, None, None], jpos[:, :, None], slot]  # (N, 2, d, d comp, na+nq)
    re = 2 * na + nq
    Ge = np.zeros((N, 2, d, d, re))
    Ge[:, 0, :, :, :na] = rows[:, 0, :, :, :na]
    Ge[:, 1, :, :, na:2 * na] = rows[:, 1, :, :, :na]
    Ge[..., 2 * na:] = rows[..., na:]
    Ge *= (o * valid[:, None])[:, :, None, None, None]
    Jinv = maps.Jinv[flat]
    ref = reference_lift(d)
    scale = maps.facet_areas[flat[:, None], lf] / ref.areas[lf]  # (N, 2)
    Gh = sum(Jinv[:, None, None, :, jj, None] * Ge[:, :, :, jj, None, :] for jj in range(d))
    Gh *= scale[:, :, None, None, None]
    Gh = Gh.reshape(N, nsel, re)
    cidx = np.concatenate([jpos[:, :1] * na + np.arange(na), jpos[:, 1:] * na + np.arange(na),
                           np.broadcast_to(kf * na + np.arange(nq), (N, nq))], axis=1)  # (N, re)
    TP = state.TP[flat]
    Q = np.matmul(np.swapaxes(TP, 1, 2), state.A @ TP) * w[:, None, None]
    plastic = np.zeros(N, dtype=bool)
    if H > 0:  # the plastic part's Gauss-Newton term and curvature at the current stresses
        sig4 = lifted_stresses(maps, faces, t, flat, TP, state.scale[flat], state).reshape(N, d1, d1, k)
        vm = von_mises(sig4)
        eta = np.maximum(vm - state.sy, 0.0)
        nrm = 1.5 * (sig4 @ state.Dv.T) / np.maximum(vm, 1e-300)[..., None]
        nrm = np.where((eta > 0)[..., None], nrm, 0.0)
        plastic = (eta > 0).any(axis=(1, 2)) & valid
    Hh = np.empty((N, nsel, nsel))
    for v in range(Lsel.shape[0]):
        idx = np.flatnonzero(le == v)
        if idx.size == 0:
            continue
        Hh[idx] = (Q[idx].reshape(idx.size, -1) @ HQ[v]).reshape(idx.size, nsel, nsel)
        pi = idx[plastic[idx]]
        if pi.size:
            nt = np.matmul(nrm[pi].reshape(pi.size, d1 * d1, k), TP[pi])  # (P, s b, m)
            L4 = Lsel[v].reshape(d1 * d1, mm, nsel)
            Ln = np.matmul(nt[:, :, None, :], L4[None])[:, :, 0, :].reshape(pi.size, d1, d1, nsel)
            MLn = np.matmul(M, Ln).reshape(pi.size, d1 * d1, nsel)
            Ln = Ln.reshape(pi.size, d1 * d1, nsel)
            Hh[pi] += np.matmul(np.swapaxes(Ln, 1, 2), MLn) * (w[pi] / H)[:, None, None]
            # Newton's curvature term: sum_sb (M eta)_sb / vm_sb (1.5 Dv - n n^T) in the lifted dofs
            c = np.where(eta[pi] > 0, (eta[pi] @ M) / np.maximum(vm[pi], 1e-300), 0.0).reshape(pi.size, -1)
            c = c * (w[pi] / H)[:, None]
            Dq = np.matmul(np.swapaxes(TP[pi], 1, 2), 1.5 * state.Dv @ TP[pi])  # (P, m, m)
            Hh[pi] += ((c[:, :, None, None] * Dq[:, None]).reshape(pi.size, -1) @ HD[v]).reshape(pi.size, nsel, nsel)
            Hh[pi] -= np.matmul(np.swapaxes(Ln * c[:, :, None], 1, 2), Ln)
    He = np.matmul(np.swapaxes(Gh, 1, 2), np.matmul(Hh, Gh))  # (N, re, re)
    hidx = (ring[:, None, None] * r + cidx[:, :, None]) * r + cidx[:, None, :]
    return np.bincount(hidx.ravel(), He.ravel(), minlength=m_r * r * r).reshape(m_r, r, r)


def compiled_ring_step(b: RingBatch, points, maps: ElementMaps, faces: Faces, rings, t: np.ndarray, volumes,
                       state: SweepState) -> np.ndarray:
    """One Newton step of J on each ring of the batch (module docstring), in compiled loops ring by ring
    (:func:`~elastoplast.bounds.local.kernel.ring_newton`), written into ``t``; returns each ring's gain."""
    from elastoplast.bounds.local.kernel import ring_newton

    d = maps.J.shape[1]
    Lfull, AV = state.ops.Lfull, state.ops.AV
    pairs, tri, HQp, Lsel, LselT = packed_hessian_operator(d)
    gain = np.zeros(b.E.shape[0])

    def ready(*arrays):  # one compiled signature: every array C-contiguous and writable (a read-only view
        # is copied; t, written in place, is C-contiguous and writable already)
        return tuple(np.require(a, requirements=("C", "W")) if isinstance(a, np.ndarray) and a is not t else a
                     for a in arrays)

    batch = ready(b.E, b.valid, b.le, b.lf, b.j, b.o.astype(float), b.F, b.s, b.end, b.Nb, d if d == 3 else 1)
    geometry = ready(points, faces.nodes, rings.point, rings.ell, b.ent)
    field = ready(t, faces.face, faces.slot, state.sign, maps.Jinv, state.scale, state.TP, state.base, volumes)
    material = ready(state.A, state.M, state.sy, state.H, state.Dv)
    operators = ready(Lfull, Lsel, LselT, HQp, pairs, tri, AV)
    obstacle = ready(state.contact, state.psi)
    control = (np.array(STEPS), RIDGE, LAM_MARGIN)
    args = [batch, geometry, field, material, operators, obstacle, control, gain]
    in_slices(ring_newton, b.E.shape[0], args, least=RING_SLICE, per_thread=RING_SLICES_PER_THREAD)
    return gain


def in_slices(kernel, m: int, args: list, least: int = 64, per_thread: int = 1) -> None:
    """``kernel(lo, hi, *args)`` over ``range(m)`` cut in ``per_thread`` slices per thread of
    :data:`KERNEL_THREADS`, of at least ``least`` each, run in :func:`kernel_pool` (the kernels
    release the GIL and their slices write apart; a free thread takes the next slice, which
    evens out slices of unequal cost), or in one call where there is room for one slice only."""
    cuts = np.linspace(0, m, min(KERNEL_THREADS * per_thread, max(1, m // least)) + 1).astype(int)
    if cuts.size == 2:
        kernel(0, m, *args)
        return
    list(kernel_pool().map(lambda lo_hi: kernel(lo_hi[0], lo_hi[1], *args), zip(cuts[:-1], cuts[1:])))


def kernel_pool() -> ThreadPoolExecutor:
    """The threads of :func:`in_slices`, started once per process (a pool per call cost a
    thread start per slice, as much as a few rings' step). Per process: a child forked after
    the pool ran inherits the pool but not its threads, and would wait on it forever."""
    return process_pool(os.getpid())


@lru_cache(maxsize=None)
def process_pool(pid: int) -> ThreadPoolExecutor:
    """:func:`kernel_pool` of the process ``pid``."""
    return ThreadPoolExecutor(KERNEL_THREADS, thread_name_prefix=f"elastoplast-kernel-{pid}")


@lru_cache(maxsize=None)
def packed_hessian_operator(d: int):
    """``(pairs (np, 2), tri (nt, 2), HQp (n_le, nt, np), Lsel, LselT)``: :func:`reference_operators`'
    ``HQ`` on the pairs ``p <= q`` of the symmetric ``Q`` (the two orders summed) and the entries
    ``x <= y`` of the symmetric element Hessian; its ``Lsel (n_le, S, nsel)`` and the transpose
    ``(n_le, nsel, S)``, both C-contiguous (what the compiled step reads)."""
    _, sel, Lsel, HQ, _, _ = reference_operators(d)
    m = len(MANDEL_PAIRS[d])
    nsel = sel.shape[1]
    pairs = np.array([(p, q) for p in range(m) for q in range(p, m)], dtype=np.int64)
    tri = np.array([(x, y) for x in range(nsel) for y in range(x, nsel)], dtype=np.int64)
    H4 = HQ.reshape(-1, m, m, nsel, nsel)
    both = H4 + np.swapaxes(H4, 1, 2) * 1.0
    both[:, np.arange(m), np.arange(m)] *= 0.5
    HQp = both[:, pairs[:, 0], pairs[:, 1]][:, :, tri[:, 0], tri[:, 1]]  # (n_le, np, nt)
    return (pairs, tri, np.ascontiguousarray(np.swapaxes(HQp, 1, 2)), np.ascontiguousarray(Lsel),
            np.ascontiguousarray(np.swapaxes(Lsel, 1, 2)))


def ring_corrections(B: np.ndarray, y: np.ndarray, nq: int) -> np.ndarray:
    """``(m, kf, d d)``: each ring face's traction change ``B (alpha_f, q)`` for the rings'
    unknowns ``y (m, kf na + nq)`` (its faces' ``alpha``, then the ring's ``q``; ``B`` from
    :func:`ring_face_bases`)."""
    m, kf = B.shape[:2]
    na = B.shape[3] - nq
    yf = np.concatenate([y[:, :kf * na].reshape(m, kf, na), np.broadcast_to(y[:, None, kf * na:], (m, kf, nq))], axis=2)
    return np.matmul(B, yf[..., None])[..., 0]


def scaled_system(Hr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ds, Hs, dead)``: the rings' Hessians ``Hr (m, r, r)`` Jacobi-scaled (``Hs = D Hr D``,
    ``D = diag(ds)``) with the relative :data:`RIDGE` on the diagonal, and the unknowns
    without curvature (``dead``: unit diagonal in ``Hs``, ``ds`` 1; their step is zero)."""
    r = Hr.shape[1]
    diag = np.einsum("mii->mi", Hr)
    dead = ~(diag > 0)
    ds = np.where(dead, 1.0, 1.0 / np.sqrt(np.where(dead, 1.0, diag)))
    Hs = Hr * ds[:, :, None] * ds[:, None, :]
    Hs[:, np.arange(r), np.arange(r)] += dead + RIDGE
    return ds, Hs, dead


def lifted_stresses(maps: ElementMaps, faces: Faces, t: np.ndarray, E: np.ndarray, TP: np.ndarray,
                    scale: np.ndarray, state: SweepState) -> np.ndarray:
    """``(N, (d+1)^2, k)``: the sub-vertex stresses of the elements ``E`` lifted from the facet
    tractions ``t`` (their double Piola maps ``TP``, facet scales ``scale (N, d+1)``: physical
    over reference facet measures; plus ``state.base``)."""
    N, d1 = E.size, maps.J.shape[1] + 1
    that = np.matmul(element_tractions(faces, t, E), np.swapaxes(maps.Jinv[E], 1, 2)[:, None]) \
        * scale[:, :, None, None]
    Sig = (that.reshape(N, -1) @ state.ops.Lfull.T).reshape(N, d1 * d1, -1)
    return np.matmul(Sig, np.swapaxes(TP, 1, 2)) + state.base[E][:, None, :]


#: passes of the round-off repair at most (each visits every colour)
REPAIR_PASSES = 4
#: the element imbalance (relative to ``|C_e| max|t|``) below which the repair stops: round-off
#: (the lift leaves an element's imbalance on its facets in the physical metric,
#: :func:`~elastoplast.bounds.local.lift.lift`; before its refinement it amplified it up to 1e4
#: times on elements of condition number 100-150)
REPAIR_TOL = 2e-15
#: the round-off repair stops once a pass leaves the largest imbalance above this share of the
#: last (at the round-off of the rings' own solves: on the default 3D problem at 98,304
#: tetrahedra, from a P1 solution to 1e-13, 1.8e-14 went to 2.72e-15 after 4 passes, 2.73e-15
#: after 8 and 2.78e-15 after 16)
STALL = 0.9
#: a pass of the repair visits the rings with an element above this share of its tolerance
#: (then the elements just below it are repaired along with their neighbours). Same start as for
#: STALL (98,304 tetrahedra): every ring in every pass 40.7 s to 1.83e-15; this share 1: 2.9 s to
#: 2.72e-15; 0.5: 2.6 s to 2.33e-15; 0.1: 5.0 s to 1.84e-15
VISIT = 0.5


def ring_repair(points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray, batches: list[RingBatch],
                free: np.ndarray, tol: float, passes: int) -> tuple[np.ndarray, float, float]:
    """The round-off repair of the elements' force and moment balance, ring by ring: on each
    ring, the least-norm correction of its faces' free traction components that zeroes the
    balance rows of its elements (rows normalised; ``(C C^T + eps I)`` solved and refined
    once, so a ring's own net imbalance, which it cannot change, is left for the next
    colour). Passes over the colours until the largest relative imbalance
    (:func:`~elastoplast.bounds.local.energy.element_imbalance`) is at most ``tol``, or until a pass
    lowers it by less than :data:`STALL`; a pass visits only the rings with an element above
    ``VISIT * tol`` (a ring's correction changes the balance of its own elements only).
    Returns ``(t, before, after)``."""
    from elastoplast.bounds.local.energy import element_imbalance

    t = t.copy()
    imbalance = element_imbalance(points, cells, maps, faces, t)
    before = after = float(imbalance.max(initial=0.0))
    _, sel, _, _, _, AV = reference_operators(cells.shape[1] - 1)
    for _ in range(passes):
        if after <= tol:
            break
        above = imbalance > VISIT * tol
        for b in batches:
            keep = (above[b.E] & b.valid).any(axis=1)
            if not keep.any():
                continue
            if not keep.all():
                b = subset(b, keep)
            for part in ring_slices(b, REPAIR_CHUNK):
                repair_rings(part, points, cells, maps, faces, t, free, sel, AV)
        imbalance = element_imbalance(points, cells, maps, faces, t)
        last, after = after, float(imbalance.max(initial=0.0))
        if after > STALL * last:
            break  # at the round-off of the rings' own solves
    return t, before, after


#: rings per block of the repair's batched solves: a colour's dense ring systems at once took
#: 500 MB above the field on the default 3D problem at 98,304 tetrahedra (its largest colours
#: hold some 10,000 rings of ``(ke nb) x (kf d d)`` rows and columns); blocks of this size keep the
#: temporaries near 20 MB and the numpy calls long enough that their overhead does not show
REPAIR_CHUNK = 512


def ring_slices(b: RingBatch, size: int):
    """The rings of a batch in consecutive blocks of at most ``size`` (views: an interior
    batch's broadcast ``Nb`` stays one array)."""
    return (subset(b, sl) for sl in blocks(b.E.shape[0], size))


def repair_rings(b: RingBatch, points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray, free: np.ndarray,
                 sel: np.ndarray, AV: np.ndarray) -> None:
    """One step of :func:`ring_repair` on the rings of ``b`` (of one colour): the least-norm
    correction of their faces' free components that zeroes their elements' balance rows, added into ``t``."""
    from elastoplast.bounds.local.energy import balance_matrices

    d = cells.shape[1] - 1
    dd = d * d
    m_r, ke = b.E.shape
    kf = b.F.shape[1]
    flat = b.E.ravel()
    N = flat.size
    C = balance_matrices(points, cells[flat], maps.facet_areas[flat])  # (N, nb, nte)
    nb = C.shape[1]
    te = element_tractions(faces, t, flat).reshape(N, -1)
    res = -np.einsum("nrx,nx->nr", C, te) * b.valid.ravel()[:, None]
    lf = b.lf.reshape(N, 2)
    slot = faces.slot[flat[:, None, None], lf[:, :, None], AV[lf]]  # (N, 2, d)
    col = (b.j.reshape(N, 2)[:, :, None] * d + slot)[..., None] * d + np.arange(d)  # (N, 2, d, d)
    fr = free[b.F.reshape(-1)].reshape(m_r, kf, d) & (b.F >= 0)[..., None]
    ring = np.repeat(np.arange(m_r), ke)
    ok = fr[ring[:, None, None], b.j.reshape(N, 2)[:, :, None], np.arange(d)[None, None, :]]  # (N, 2, d comp)
    sgn = faces.sign[flat[:, None], lf] * b.valid.ravel()[:, None]  # (N, 2)
    Csel = np.take_along_axis(C, np.broadcast_to(sel[b.le.ravel()][:, None, :], (N, nb, sel.shape[1])), axis=2)
    Csel = Csel.reshape(N, nb, 2, d, d) * (sgn[:, None, :, None, None] * ok[:, None, :, None, :])
    ncol = kf * dd
    Cs = np.zeros((m_r, ke * nb, ncol))
    lin = (np.arange(N * nb).reshape(N, nb, 1) * ncol + col.reshape(N, 1, -1)).ravel()
    Cs.reshape(-1)[lin] = Csel.reshape(-1)
    rhs = res.reshape(m_r, ke * nb)
    nrm = np.linalg.norm(Cs, axis=2)
    live = nrm > 0
    nrm = np.where(live, nrm, 1.0)
    Cs, rhs = Cs / nrm[..., None], np.where(live, rhs / nrm, 0.0)
    G = np.matmul(Cs, np.swapaxes(Cs, 1, 2)) + 1e-10 * np.eye(ke * nb)
    x = np.zeros((m_r, ncol))
    for _ in range(2):
        r = rhs - np.matmul(Cs, x[..., None])[..., 0]
        x += np.matmul(np.swapaxes(Cs, 1, 2), np.linalg.solve(G, r[..., None]))[..., 0]
    ok_f = b.F >= 0
    t.reshape(t.shape[0], -1)[b.F[ok_f]] += x.reshape(m_r, kf, dd)[ok_f]
