"""The contact pressure of the local lower bound, and the stress correction next to Γ0 it needs.

Element equilibration reproduces the nodal balance of the discrete stress. At the nodes
of Γ0 that balance is with the discrete contact forces ``r_a``, and the moments
``int_f lam b_a`` of a linear pressure ``lam >= 0`` cannot reproduce every ``r_a >= 0``
(where the contact ends, a node with ``r_a = 0`` next to one with ``r_a > 0`` would need
a negative pressure on one facet). So the pressure is chosen first and the discrete
stress is corrected to balance it:

* ``lam`` continuous and linear on Γ0 with nodal values ``r_a / m_a`` (``m_a`` the lumped
  facet measure around a), so ``lam >= 0`` and ``int lam = sum_a r_a``; then multiplied
  by an affine function ``1 + c_0 + c . x'`` chosen so that ``int lam = F`` exactly and
  its first moments equal those of the nodal forces (the conditions under which the
  correction below exists when no displacement is fixed near Γ0);
* a constant stress ``Delta_T`` in each element touching Γ0, of least norm, whose nodal
  forces are ``(M lam)_a - r_a`` vertically at the nodes of Γ0 and vanish at every other
  free degree of freedom. The corrected stress is in nodal balance with ``lam``.

The correction is a sparse least-norm problem on the elements touching Γ0 (a layer one
element thick: its size grows like the contact zone's facet count, not the mesh's)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from elastoplast.bounds.local.equilibrate import Faces
from elastoplast.bounds.local.lift import MANDEL_PAIRS, mandel_to_tensor
from elastoplast.linalg.direct import project_affine
from elastoplast.bounds.static import mass_matrix
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization

#: element rings around Γ0 that carry the correction (one ring is too thin: carrying
#: self-balanced nodal forces across a thin layer takes bending stresses ~ 1/h larger)
LAYER_RINGS = 3
#: the layer also reaches this many (largest) Γ0 facet lengths away from Γ0: rings of a graded
#: mesh are thin, and the correction grows like one over the layer's depth
LAYER_DEPTH = 3.0
#: contact zones up to this many nodes are fitted with dense algebra (the moment rows couple every node)
DENSE_NODES = 2000
#: the correction's relative residual above which the contact layer is refused
LAYER_TOL = 1e-13
#: rings the layer may grow by when its correction is not exact (measured: an adaptively
#: refined 3D default problem, 19,780 tetrahedra, left 1.3e-11 with 3 rings, round-off with 4)
LAYER_GROWTH = 3


def nodal_pressure(disc: Discretization, facet_nodes: np.ndarray, measure: np.ndarray,
                   contact_force: np.ndarray, max_rounds: int = 30) -> np.ndarray:
    """Nodal values (indexed by mesh node, zero off Γ0) of the continuous linear pressure
    ``lam >= 0`` whose nodal moments ``(M lam)_a`` are nearest to the contact forces ``r_a``
    (least squares) with ``int lam = F`` and the first moments ``int x' lam = sum_a x'_a r_a``
    exactly: an active set, pressures that come out negative are fixed at zero and the
    rest solved again (a sparse problem on the nodes of Γ0)."""
    d = disc.dim
    n_nodes = disc.mesh.n_nodes
    nodes, local = np.unique(facet_nodes, return_inverse=True)
    local = local.reshape(facet_nodes.shape)
    nc = nodes.size
    Mh = mass_matrix(d - 1)
    rr = np.broadcast_to(local[:, :, None], (local.shape[0], d, d)).ravel()
    cc = np.broadcast_to(local[:, None, :], (local.shape[0], d, d)).ravel()
    M = sp.csr_matrix(((measure[:, None, None] * Mh).ravel(), (rr, cc)), shape=(nc, nc))
    r_all = np.zeros(n_nodes)
    r_all[disc.contact_nodes] = np.asarray(contact_force, dtype=float)
    r = r_all[nodes]
    basis = np.hstack([np.ones((nc, 1)), disc.mesh.points[nodes, :-1]])  # (nc, d)
    C = (M @ basis).T  # int phi_k lam = (basis^T M lam)_k
    c = basis.T @ r
    c[0] = disc.force
    # the force and moment rows are constraints (the layer is a free body: its correction can only
    # carry a mismatch of zero net force and moment, so a weighted fit left 4e-11 on adapted meshes)
    zero = np.zeros(nc, dtype=bool)
    lam = np.zeros(nc)
    for _ in range(max_rounds):
        F = np.flatnonzero(~zero)
        MF = M[:, F]
        CF = C[:, F]
        rhs = np.concatenate([MF.T @ r, c])
        if F.size <= DENSE_NODES:
            N = (MF.T @ MF).toarray()
            K = np.block([[N, CF.T], [CF, np.zeros((C.shape[0], C.shape[0]))]])
            sol = np.linalg.lstsq(K, rhs, rcond=None)[0]
        else:
            K = sp.bmat([[MF.T @ MF, sp.csr_matrix(CF.T)], [sp.csr_matrix(CF), None]]).tocsc()
            sol = spla.spsolve(K, rhs)
        lamF = sol[:F.size]
        lam[:] = 0.0
        lam[F] = lamF
        neg = lam < 0
        if not neg.any():
            break
        zero |= neg
    else:
        raise InputError("boundary.contact", "no non-negative contact pressure found for the local lower bound")
    total = float(np.sum(M @ lam))
    if not total > 0:
        raise InputError("boundary.contact", "the contact forces of the solution carry no load: no local lower bound")
    lam *= disc.force / total  # int lam = F exactly
    out = np.zeros(n_nodes)
    out[nodes] = lam
    return out


def contact_pressure_and_correction(disc: Discretization, faces: Faces, S: np.ndarray,
                                    contact_force: np.ndarray, rings: int = LAYER_RINGS) -> tuple[np.ndarray, np.ndarray]:
    """``(lam (n_cf, d), Delta (n, d, d))``: the pressure at the vertices of the Γ0 facets
    (in the order of ``disc.facet_topology.contact_index``) and the stress correction."""
    d = disc.dim
    topo = disc.facet_topology
    cf = faces.n_interior + topo.contact_index
    fn = faces.nodes[cf]
    measure = faces.measure[cf]
    lam_nodes = nodal_pressure(disc, fn, measure, contact_force)
    lam = lam_nodes[fn]
    n_nodes = disc.mesh.n_nodes
    # mismatch at the Γ0 nodes: (M lam)_a - r_a
    moments = np.zeros(n_nodes)
    np.add.at(moments, fn.ravel(), (measure[:, None] * (lam @ mass_matrix(d - 1))).ravel())
    r = np.zeros(n_nodes)
    r[disc.contact_nodes] = contact_force
    delta = np.zeros((n_nodes, d))
    delta[:, -1] = moments - r
    on_contact = np.zeros(n_nodes, dtype=bool)
    on_contact[fn.ravel()] = True
    worst = np.inf
    for deeper in range(LAYER_GROWTH + 1):  # a layer too thin to carry the mismatch exactly grows by a ring
        dS, worst = layer_correction(disc, on_contact, measure, delta, r, rings + deeper)
        if worst <= LAYER_TOL:
            return lam, dS
    raise InputError("boundary.contact", f"the stress correction next to Γ0 leaves a relative residual "
                     f"{worst:.1e} (> {LAYER_TOL:.0e}) with layers of {rings} to {rings + LAYER_GROWTH} rings: "
                     "no local lower bound")


def layer_correction(disc: Discretization, on_contact: np.ndarray, measure: np.ndarray, delta: np.ndarray,
                     r: np.ndarray, rings: int) -> tuple[np.ndarray, float]:
    """``(Delta (n, d, d), residual)``: the least-norm constant stress per element of the layer of
    ``rings`` rings (and :data:`LAYER_DEPTH` facet lengths) around the Γ0 nodes ``on_contact``
    whose nodal forces are ``-delta`` at the free dofs, and its largest relative residual
    (against the largest contact force ``r``)."""
    d = disc.dim
    n_nodes = disc.mesh.n_nodes
    cells = disc.mesh.cells
    near = on_contact.copy()
    for _ in range(rings - 1):  # grow the layer by whole vertex stars
        near[cells[near[cells].any(axis=1)].ravel()] = True
    # and to a depth of LAYER_DEPTH contact facets (on graded meshes the rings are thin)
    from scipy.spatial import cKDTree

    depth = LAYER_DEPTH * float(measure.max(initial=0.0))
    dist, _ = cKDTree(disc.mesh.points[on_contact]).query(disc.mesh.points, distance_upper_bound=depth)
    near |= dist <= depth
    layer = np.flatnonzero(near[cells].any(axis=1))
    ms = len(MANDEL_PAIRS[d])
    E = mandel_to_tensor(np.eye(ms), d)  # (ms, d, d)
    g = disc.grads[layer]  # (L, d+1, d)
    # coefficient of Delta_{T,q} in the nodal force (node of T's vertex a, component j)
    coef = disc.volumes[layer, None, None, None] * np.einsum("qij,laj->laiq", E, g)  # (L, d+1, d, ms)
    rows = (cells[layer][:, :, None] * d + np.arange(d))[..., None]  # dof index
    cols = (np.arange(layer.size)[:, None, None, None] * ms + np.arange(ms))
    rows, cols, vals = (np.broadcast_to(a, coef.shape).ravel() for a in (rows, cols, coef))
    free = np.ones(n_nodes * d, dtype=bool)
    free[disc.fixed] = False
    dofs = np.unique(rows)
    dofs = dofs[free[dofs]]
    where = -np.ones(n_nodes * d, dtype=np.int64)
    where[dofs] = np.arange(dofs.size)
    keep = where[rows] >= 0
    B = sp.csc_matrix((vals[keep], (where[rows[keep]], cols[keep])), shape=(dofs.size, layer.size * ms))
    b = delta.ravel()[dofs]
    w = np.repeat(1.0 / np.sqrt(disc.volumes[layer]), ms)  # least norm in sum |T| |Delta_T|^2
    y, res = project_affine(B @ sp.diags(w), b, np.zeros(B.shape[1]))
    x = w * y
    scale = max(np.abs(r).max(initial=0.0), np.finfo(float).tiny)
    worst = float(np.abs(B @ x - b).max(initial=0.0)) / scale
    dS = np.zeros((disc.n_elements, d, d))
    dS[layer] = mandel_to_tensor(x.reshape(-1, ms), d)
    return dS, worst
