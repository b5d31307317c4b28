"""Hencky elasto-plastic material in Mandel (orthonormal) vector notation.

Stresses and strains are vectors whose dot product is the tensor contraction
``sigma : eps`` (docs/math.md):

* 3D: ``(11, 22, 33, sqrt2*23, sqrt2*13, sqrt2*12)``, six components;
* plane strain: ``(11, 22, 33, sqrt2*12)``, four components, where ``eps33 = 0``
  but ``sigma33`` is a free stress component that enters von Mises.

Everything here works on arrays shaped ``(n_elements, n_components)``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from elastoplast.errors import InputError, short_repr
from elastoplast.limits import blocks

SQRT_3_2 = np.sqrt(1.5)


def n_components(dim: int) -> int:
    """Number of Mandel components of a symmetric tensor in ``dim`` (2 = plane strain)."""
    return {2: 4, 3: 6}[dim]


def identity_vector(dim: int) -> np.ndarray:
    """The identity tensor ``I`` in Mandel notation (``I : tau = tr tau``)."""
    m = np.zeros(n_components(dim))
    m[:3] = 1.0
    return m


def deviator_matrix(dim: int) -> np.ndarray:
    """Matrix of ``dev tau = tau - (tr tau / 3) I``; symmetric and idempotent."""
    m = identity_vector(dim)
    return np.eye(m.size) - np.outer(m, m) / 3.0


def deviator(tau: np.ndarray) -> np.ndarray:
    """Deviatoric part of each row of ``tau`` (shape ``(n, k)``)."""
    out = tau.copy()
    mean = tau[..., :3].sum(axis=-1, keepdims=True) / 3.0
    out[..., :3] -= mean
    return out


#: rows of :func:`von_mises` per block: a whole field at once made temporaries of three times
#: its size (the local lower bound's field on the split mesh of 98,304 tetrahedra: 75 MB each)
VON_MISES_ROWS = 1 << 16


def von_mises(sigma: np.ndarray) -> np.ndarray:
    """Von Mises equivalent stress ``sqrt(3/2) |dev sigma|`` of each row (of the last axis), by
    blocks of :data:`VON_MISES_ROWS` rows (each row's value is the same either way)."""
    sigma = np.asarray(sigma)
    if sigma.ndim < 2 or sigma.size <= VON_MISES_ROWS * sigma.shape[-1]:
        return SQRT_3_2 * np.linalg.norm(deviator(sigma), axis=-1)
    flat = sigma.reshape(-1, sigma.shape[-1])
    out = np.empty(flat.shape[0])
    for sl in blocks(flat.shape[0], VON_MISES_ROWS):
        out[sl] = SQRT_3_2 * np.linalg.norm(deviator(flat[sl]), axis=-1)
    return out.reshape(sigma.shape[:-1])


@dataclass(frozen=True)
class Material:
    """Isotropic elasticity with von Mises yield and linear isotropic hardening.

    ``hardening`` is the modulus H of docs/math.md (uniaxial
    ``sigma = sigma_y + H eps_p``); ``hardening == 0`` is perfect plasticity.
    """

    E: float
    nu: float
    yield_stress: float
    hardening: float

    def __post_init__(self) -> None:
        """The admitted ranges (docs/problem-files.md), named ``material.<key>``, for every
        Material: one made by ``dataclasses.replace`` with nu = 0.7 (a negative bulk
        modulus) was solved. ``yield_stress`` may be infinite (an elastic body)."""
        for key in ("E", "nu", "yield_stress", "hardening"):
            value = getattr(self, key)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or math.isnan(value):
                raise InputError(f"material.{key}", f"must be a number, got {short_repr(value)}")
        if not 0 < self.E < math.inf:
            raise InputError("material.E", f"must be a finite number > 0, got {self.E!r}")
        if not -1.0 < self.nu < 0.5:
            raise InputError("material.nu", f"must lie in (-1, 0.5), got {self.nu!r}")
        if not self.yield_stress > 0:
            raise InputError("material.yield_stress", f"must be > 0, got {self.yield_stress!r}")
        if not 0 <= self.hardening < math.inf:
            raise InputError("material.hardening", f"must be a finite number >= 0, got {self.hardening!r}")

    @property
    def mu(self) -> float:
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lam(self) -> float:
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def bulk(self) -> float:
        return self.lam + 2.0 * self.mu / 3.0

    def stiffness(self, dim: int) -> np.ndarray:
        """``C = 2 mu I + lam m m^T`` acting on Mandel vectors."""
        m = identity_vector(dim)
        return 2.0 * self.mu * np.eye(m.size) + self.lam * np.outer(m, m)

    def compliance(self, dim: int) -> np.ndarray:
        """``A = C^{-1} = (I - lam/(2 mu + 3 lam) m m^T) / (2 mu)`` in closed form."""
        m = identity_vector(dim)
        c = self.lam / (2.0 * self.mu + 3.0 * self.lam)
        return (np.eye(m.size) - c * np.outer(m, m)) / (2.0 * self.mu)

    def max_stiffness_eigenvalue(self) -> float:
        """``lambda_max(C) = 3 K = E / (1 - 2 nu)`` for nu >= 0, else ``2 mu``."""
        return max(3.0 * self.bulk, 2.0 * self.mu)


@dataclass(frozen=True)
class Prestate:
    """The material state a backward-Euler step of Prandtl-Reuss' law starts from.

    ``sigma`` ``(n, k)`` and ``xi`` ``(n,)`` are the stresses and hardening
    stresses at the end of the last step; ``strain = A sigma`` is the elastic
    strain they hold, computed once in the real material's compliance (the
    proximal maps of ALG2 use other moduli but the same shift). The step's
    return mapping is Hencky's at the shifted strain ``eps + A sigma`` with the
    yield stress raised to ``sigma_y + xi`` (see :func:`return_mapping`).
    ``displacement``: the largest displacement the body has reached (the scale
    of the step's total displacement, for the certificate's relative residuals).
    """

    sigma: np.ndarray
    xi: np.ndarray
    strain: np.ndarray
    displacement: float = 0.0

    @classmethod
    def of(cls, material: "Material", sigma: np.ndarray, xi: np.ndarray, displacement: float = 0.0) -> "Prestate":
        sigma = np.asarray(sigma, dtype=float)
        dim = 2 if sigma.shape[-1] == 4 else 3
        return cls(sigma, np.asarray(xi, dtype=float), sigma @ material.compliance(dim), float(displacement))

    def rows(self, index) -> "Prestate":
        """The state of the elements ``index`` (an index array or a mask)."""
        return Prestate(self.sigma[index], self.xi[index], self.strain[index], self.displacement)

    def scaled(self, stress: float, strain: float, displacement: float = 1.0) -> "Prestate":
        """The same state in other units (stresses divided by ``stress``, strains by
        ``strain``, displacements by ``displacement``)."""
        return Prestate(self.sigma / stress, self.xi / stress, self.strain / strain, self.displacement / displacement)


def _trial(material: Material, eps: np.ndarray, state: Prestate | None):
    """``(sigma_tr, s, |s|, f)`` of the radial return: the trial stress, its deviator
    and norm, and the yield function ``sqrt(3/2)|s| - sigma_y - xi_n``."""
    dim = 2 if eps.shape[-1] == 4 else 3
    shifted = eps if state is None else eps + state.strain
    sigma = shifted @ material.stiffness(dim)
    s = deviator(sigma)
    norm_s = np.linalg.norm(s, axis=-1)
    limit = material.yield_stress if state is None else material.yield_stress + state.xi
    return sigma, s, norm_s, SQRT_3_2 * norm_s - limit


def return_mapping(material: Material, eps: np.ndarray,
                   state: Prestate | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form projection of ``(C eps, 0)`` onto the admissible set D.

    This is the map R of docs/certificate.md, applied to every row of ``eps``
    (shape ``(n, k)``), projecting in the energy metric ``[.,.]``::

        sigma_tr = C eps,  s = dev sigma_tr,  f = sqrt(3/2)|s| - sigma_y
        f <= 0:  sigma = sigma_tr,  xi = 0
        f  > 0:  dkappa = f / (3 mu + H),
                 sigma = sigma_tr - 2 mu sqrt(3/2) dkappa s/|s|,  xi = H dkappa

    Returns ``(sigma, xi, dkappa)``; ``dkappa`` is the equivalent plastic strain.

    With a ``state`` (one row per row of ``eps``) this is the step's map R_n of
    docs/evolution.md: the projection of ``(sigma_n + C eps, xi_n)``, i.e. the
    trial stress ``C (eps + A sigma_n)``, the yield stress ``sigma_y + xi_n``, and
    ``xi = xi_n + H dkappa``; ``dkappa`` is then the step's increment.
    """
    sigma, s, norm_s, f = _trial(material, eps, state)
    dkappa = np.where(f > 0.0, f, 0.0) / (3.0 * material.mu + material.hardening)
    safe = np.where(norm_s > 0.0, norm_s, 1.0)
    sigma = sigma - (2.0 * material.mu * SQRT_3_2 * dkappa / safe)[:, None] * s
    xi = material.hardening * dkappa
    return sigma, (xi if state is None else state.xi + xi), dkappa


def consistent_tangent(material: Material, eps: np.ndarray,
                       state: Prestate | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return mapping and its derivative ``d sigma / d eps`` per row of ``eps``.

    Differentiating the closed form of :func:`return_mapping` with
    ``n = s/|s|``, ``q = sqrt(3/2)|s|`` (trial values) and ``Dev`` the
    deviatoric projector gives, in plastic elements,

        C_alg = C - 6 mu^2 / (3 mu + H) n n^T - 6 mu^2 dkappa / q (Dev - n n^T),

    and ``C`` in elastic ones. Returns ``(sigma, xi, C_alg)`` with ``C_alg``
    shaped ``(n, k, k)``. ``state``: as for :func:`return_mapping` (the trial
    values are then those of the shifted strain).
    """
    dim = 2 if eps.shape[-1] == 4 else 3
    sigma, xi, dkappa = return_mapping(material, eps, state)
    C = material.stiffness(dim)
    tangent = np.broadcast_to(C, (eps.shape[0],) + C.shape).copy()
    plastic = dkappa > 0.0
    if np.any(plastic):
        mu, H = material.mu, material.hardening
        _, s, norm_s, _ = _trial(material, eps[plastic], None if state is None else state.rows(plastic))
        n = s / norm_s[:, None]
        nn = n[:, :, None] * n[:, None, :]
        q = SQRT_3_2 * norm_s
        dev = deviator_matrix(dim)
        tangent[plastic] -= (6.0 * mu**2 / (3.0 * mu + H)) * nn
        tangent[plastic] -= (6.0 * mu**2 * dkappa[plastic] / q)[:, None, None] * (dev - nn)
    return sigma, xi, tangent
