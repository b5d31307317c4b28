"""The element complementary energy of the local field and what the sweeps, the descent and
the repair share with it (docs/bounds.md, "a local field").

:func:`element_energy` is J_e of sub-vertex stresses, ``w/2 sum_s sig_s (M x A) sig_s +
w/(2H) sum_s eta_s M eta_s`` with ``eta = max(0, vm - sigma_y)``: the one numpy copy (the
sweeps' and the descent's compiled loops keep a twin, ``kernel._energy``, held to this one
by ``tests/test_local_frame.py``). Beside it: the plane-strain stress map, the elements'
force and moment rows of their vertex tractions and the relative element imbalance that
the round-off repair drives to zero. (The vertex-star sweeps with an SVD basis per star
were replaced by the ring sweeps and the ring repair: in 3D a star has about 300 traction
unknowns, a ring 54.)"""

from __future__ import annotations

import numpy as np

from elastoplast.bounds.local.equilibrate import Faces, element_tractions
from elastoplast.bounds.local.lift import ElementMaps
from elastoplast.bounds.local.lift import balance_matrices as vertex_balance_matrices
from elastoplast.fem.material import Material, von_mises
from elastoplast.limits import blocks

#: elements per block of :func:`element_imbalance` (a block's balance rows and their squares:
#: some 10 kB per element; 4k elements keep them near 40 MB)
IMBALANCE_BLOCK = 1 << 12


def stress_map(dim: int, material: Material) -> np.ndarray:
    """``(k, m)``: full Mandel stress from the lifted in-plane components (plane strain:
    ``tau33 = nu (tau11 + tau22)``)."""
    if dim == 3:
        return np.eye(6)
    T = np.zeros((4, 3))
    T[[0, 1, 3], [0, 1, 2]] = 1.0
    T[2, :2] = material.nu
    return T


def balance_matrices(points: np.ndarray, cells: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``(n, nb, (d+1)(d+1)d)``: force and moment (about the centroid) of an element's outward
    vertex tractions ``t[i, a, j]`` (zero weight where a == i; :func:`~elastoplast.bounds.local.lift.balance_matrices`)."""
    return vertex_balance_matrices(points[cells], areas)


def element_energy(sig: np.ndarray, w: np.ndarray, MA: np.ndarray, M: np.ndarray, sy: float, H: float):
    """``J_e`` of sub-vertex stresses ``sig (n, s, b, k)`` (sub volumes ``w (n,)``; ``MA = M (x) A``)."""
    n, s = sig.shape[:2]
    flat = sig.reshape(n, s, -1)
    el = 0.5 * w * np.einsum("nsx,nsx->n", flat, flat @ MA.T)
    if H > 0:
        eta = np.maximum(von_mises(sig) - sy, 0.0)
        el = el + 0.5 / H * w * np.einsum("nsb,nsb->n", eta, eta @ M)
    return el


def element_imbalance(points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray) -> np.ndarray:
    """``(n,)``: each element's largest balance-row residual of the tractions ``t``,
    relative to that row's norm times ``max |t|``."""
    out = np.empty(cells.shape[0])
    for sl in blocks(cells.shape[0], IMBALANCE_BLOCK):  # the rows of a whole mesh are 6 times its tractions
        C = balance_matrices(points, cells[sl], maps.facet_areas[sl])
        te = element_tractions(faces, t, sl).reshape(C.shape[0], -1)
        out[sl] = (np.abs(np.einsum("nrx,nx->nr", C, te)) / np.maximum(np.linalg.norm(C, axis=2), 1e-300)).max(axis=1)
    return out / max(np.abs(t).max(initial=0.0), np.finfo(float).tiny)
