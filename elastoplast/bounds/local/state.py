"""What the local bound's sweeps and descent read besides the facet tractions, built once:
:class:`SweepState` (the material's operators, the reference lift's operators, each element's
double Piola map and facet scales, the Γ0 facets and their obstacle weights, the descent's
per-element buffers). Frozen: nothing is added to it later; its arrays are read by the
compiled loops (the two buffers are the only ones written, by the descent's energy)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from elastoplast.bounds.local.energy import stress_map
from elastoplast.bounds.local.equilibrate import Faces
from elastoplast.bounds.local.lift import MANDEL_PAIRS, ElementMaps, mandel_to_tensor, reference_lift, tensor_to_mandel
from elastoplast.bounds.local.rings import local_entities
from elastoplast.bounds.static import mass_matrix
from elastoplast.fem.material import Material, deviator_matrix
from elastoplast.limits import blocks

#: elements per block of the Piola maps of :func:`sweep_state`
PIOLA_BLOCK = 1 << 14


class ReferenceOperators(NamedTuple):
    """The reference lift's operators per local-entity class (:func:`reference_operators`)."""
    Lfull: np.ndarray  # (S, nte): sub-vertex Mandel values from the reference vertex tractions
    sel: np.ndarray  # (n_le, nsel): the element traction dofs of the two facets through each local entity
    Lsel: np.ndarray  # (n_le, S, nsel): their lift columns
    HQ: np.ndarray  # (n_le, m m, nsel nsel): the elastic Hessian's reference part
    HD: np.ndarray  # (n_le, (d+1)^2 m m, nsel nsel): the plastic curvature's reference part
    AV: np.ndarray  # (d+1, d): the vertices of each facet (local numbering)


@lru_cache(maxsize=None)
def reference_operators(d: int) -> ReferenceOperators:
    """The reference lift (S = (d+1)^2 m sub-vertex Mandel values from the nte reference
    vertex tractions), the element traction dofs of the two facets through each local
    entity (facet, vertex ascending, component), their lift columns and
    ``HQ[pq] = sum_s sum_bc M_bc L[s,b,p,:]^T L[s,c,q,:]`` and, per sub-vertex,
    ``HD[sb, pq] = L[s,b,p,:]^T L[s,b,q,:]`` (the curvature of the plastic part)."""
    d1 = d + 1
    ref = reference_lift(d)
    m = len(MANDEL_PAIRS[d])
    Lfull = ref.matrix.reshape(d1 * d1 * m, d1 * d1 * d)
    _, LF = local_entities(d)
    AV = np.array([[a for a in range(d1) if a != f] for f in range(d1)])
    sel = np.array([[(f * d1 + a) * d + i for f in LF[le] for a in AV[f] for i in range(d)] for le in range(LF.shape[0])])
    Lsel = Lfull[:, sel].transpose(1, 0, 2)  # (n_le, S, nsel)
    M = mass_matrix(d)
    L4 = Lsel.reshape(-1, d1, d1, m, sel.shape[1])
    HQ = np.einsum("bc,lsbpx,lscqy->lpqxy", M, L4, L4).reshape(LF.shape[0], m * m, -1)
    L3 = Lsel.reshape(LF.shape[0], d1 * d1, m, -1)
    HD = np.einsum("lspx,lsqy->lspqxy", L3, L3).reshape(LF.shape[0], d1 * d1 * m * m, -1)
    return ReferenceOperators(Lfull, sel, Lsel, HQ, HD, AV)


def piola(maps: ElementMaps, E: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``TP (N, k, m)``: full Mandel stress from the in-plane reference Mandel values (double Piola map)."""
    d = maps.J.shape[1]
    m = len(MANDEL_PAIRS[d])
    J, det = maps.J[E], maps.det[E]
    Eb = mandel_to_tensor(np.eye(m), d)
    JE = np.matmul(J[:, None], Eb[None])  # (N, q, d, d)
    P = tensor_to_mandel(np.matmul(JE, np.swapaxes(J, 1, 2)[:, None]), d) / det[:, None, None]  # (N, q, p)
    return np.einsum("kp,nqp->nkq", T, P)


@dataclass(frozen=True)
class SweepState:
    """What J's evaluation on the split mesh's ``n`` elements needs besides the tractions
    (:func:`sweep_state` builds it). ``k`` is the number of full Mandel components, ``m``
    the in-plane ones, ``F`` the facets."""
    T: np.ndarray  # (k, m): the stress map, in-plane Mandel values to full ones (energy.stress_map)
    A: np.ndarray  # (k, k): the compliance
    M: np.ndarray  # (d+1, d+1): the P1 mass matrix of an element over its measure
    MA: np.ndarray  # kron(M, A)
    sy: float  # the yield stress
    H: float  # the hardening modulus
    Dv: np.ndarray  # (k, k): the deviator
    base: np.ndarray  # (n, k): the plane-strain tau33 offset (2D), else zero
    ops: ReferenceOperators
    psi: np.ndarray  # (F, d): the obstacle weights q of the Γ0 facets at their vertices (J gains sum q lam)
    contact: np.ndarray  # (F,) bool: the Γ0 facets
    TP: np.ndarray  # (n, k, m): each element's double Piola map (piola)
    scale: np.ndarray  # (n, d+1): physical over reference facet measures
    sign: np.ndarray  # (n, d+1): the facets' orientations seen from each element, as floats
    J_el: np.ndarray  # (n,): the descent's buffer of each element's J_e
    g_el: np.ndarray  # (n, d+1, d+1, d): the descent's buffer of each element's gradient


def sweep_state(material: Material, maps: ElementMaps, faces: Faces, offset=None, psi=None,
                contact=None) -> SweepState:
    """:class:`SweepState` of the elements of ``maps``: ``offset`` the plane-strain ``tau33``
    offset per element (2D; default none), ``psi (F, d)`` the obstacle weights and ``contact
    (F,)`` the Γ0 facets (default: no Γ0 facet, no obstacle weight). The buffers are
    allocated, not touched (their pages cost nothing until the descent writes them)."""
    n, d = maps.J.shape[:2]
    T = stress_map(d, material)
    A = material.compliance(d)
    M = mass_matrix(d)
    base = np.zeros((n, T.shape[0]))
    if offset is not None and d == 2:
        base[:, 2] = offset
    TP = np.empty((n, T.shape[0], len(MANDEL_PAIRS[d])))
    for sl in blocks(n, PIOLA_BLOCK):  # piola's products for the whole mesh are 3 times TP
        TP[sl] = piola(maps, np.arange(sl.start, sl.stop), T)
    n_faces = faces.nodes.shape[0]
    return SweepState(T=T, A=A, M=M, MA=np.kron(M, A), sy=float(material.yield_stress), H=float(material.hardening),
                      Dv=deviator_matrix(d), base=base, ops=reference_operators(d),
                      psi=np.zeros((n_faces, d)) if psi is None else psi,
                      contact=np.zeros(n_faces, dtype=bool) if contact is None else contact,
                      TP=TP, scale=maps.facet_areas / reference_lift(d).areas, sign=faces.sign.astype(float),
                      J_el=np.empty(n), g_el=np.zeros((n, d + 1, d + 1, d)))
