"""Uzawa's iteration in a Jacobi metric: an example of a method from outside.

A projected gradient method on the displacement form (D) with a fixed step, written
against the public API only. Each iteration

1. takes the stresses of the current displacement by the return mapping,
   ``sigma = R(eps(u))``, and their nodal forces ``r = sum_T |T| B_T^T sigma_T``;
2. steps ``u* = u - rho D^-1 r`` in the metric ``D = diag(K)``, the diagonal of the
   elastic stiffness ``K = sum_T |T| B_T^T C B_T`` (Jacobi), instead of Uzawa's
   ``G = sum_T |T| B_T^T B_T`` (which needs a factorisation);
3. projects ``(u*, U)`` onto ``K_h`` in that metric, the rigid body carrying no
   weight: with a diagonal metric the projection is exact and closed-form, each
   contact node's vertical displacement ``max(u*_i, U - psi_i)`` and ``U`` the root of
   the non-decreasing piecewise-linear ``sum_i d_i max(0, U - psi_i - u*_i) = rho F``.

The step is ``rho = 1 / L`` with ``L`` Gershgorin's bound on the largest eigenvalue of
``D^-1/2 K D^-1/2``, a Lipschitz constant of the gradient of (D) in the metric ``D``
(the return mapping is no stiffer than ``C``), so the iteration converges from any
start; it is slow on fine meshes (the condition number of ``D^-1 K`` grows like
``h^-2``) and meant for small ones.

Two forms of the same method, the two a plug-in may take:

* ``run``, a plain function ``run(disc, options) -> (u, U)``: it gets the base
  options (``tol``, ``max_iter``, ``time_limit``, ``progress``), whose ``max_iter``
  of 1000 is too few here: give ``--max-iter``;
* ``METHOD``, a ``Method``: the same function with its own options class,
  :class:`JacobiOptions` (``max_iter`` 100,000 by default, ``check_every``). The
  ``pyproject.toml`` beside this file declares it as the entry point ``jacobi-uzawa``.

Either returns ``(u, U)``: the package takes the stresses by the return mapping,
builds the Solution and decides the status by its certificate at ``options.tol``.
The method stops itself on that same certificate (``ep.certify``), checked every
``check_every`` iterations, or at ``options.max_iter`` or ``options.time_limit``.

Run it (from the repository's root; README.md beside this file has more)::

    PYTHONPATH=examples/plugin_method elastoplast solve examples/plugin_method/small_2d.toml \
        --method jacobi_uzawa:METHOD --out results
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

import elastoplast as ep

#: iterations between two certificates, for the plain function ``run``
CHECK_EVERY = 50


@dataclass(frozen=True)
class JacobiOptions(ep.SolverOptions):
    """The options of :data:`METHOD`: the base ones, with more iterations by default."""

    max_iter: int = ep.option(100_000, int, "iteration limit", lo=1, hi=ep.MAX_ITER_CEILING)
    check_every: int = ep.option(CHECK_EVERY, int, "iterations between two certificates", lo=1, hi=10_000)


def step_and_metric(disc: ep.Discretization) -> tuple[float, np.ndarray]:
    """``(rho, d)``: the fixed step and the Jacobi metric (the stiffness diagonal)."""
    K = disc.weighted_gram(disc.material.stiffness(disc.dim)).tocsr()
    d = K.diagonal()
    scale = sp.diags(1.0 / np.sqrt(d))
    lipschitz = float(abs(scale @ K @ scale).sum(axis=1).max())  # Gershgorin
    return 1.0 / lipschitz, d


def project(u_star: np.ndarray, disc: ep.Discretization, d: np.ndarray, cols: np.ndarray,
            rho: float) -> tuple[np.ndarray, float]:
    """``(u, U)`` in K_h nearest ``u*`` in the metric ``d``, ``U`` pushed by ``rho F``."""
    b = disc.psi + u_star[cols]  # node i is in contact once U > b_i
    order = np.argsort(b)
    b, w = b[order], d[cols][order]
    # on [b_k, b_k+1] the first k+1 nodes are active: sum w_j (U - b_j) = rho F
    candidates = (np.cumsum(w * b) + rho * disc.force) / np.cumsum(w)
    upper = np.append(b[1:], np.inf)
    k = int(np.flatnonzero(candidates <= upper)[0])  # the equation's only root
    U = float(candidates[k])
    u = u_star.copy()
    u[cols] = np.maximum(u_star[cols], U - disc.psi)
    return u, U


def run(disc: ep.Discretization, options: ep.SolverOptions) -> tuple[np.ndarray, float]:
    """The method: ``run(disc, options) -> (u, U)``, ``u`` nodal ``(n_nodes, d)``."""
    start = time.perf_counter()
    rho, d = step_and_metric(disc)
    cols = disc.N.tocoo().col[np.argsort(disc.N.tocoo().row)]  # each contact node's vertical free dof
    u, U = np.zeros(disc.n_free), 0.0
    check_every = getattr(options, "check_every", CHECK_EVERY)
    for iteration in range(1, options.max_iter + 1):
        sigma, xi, _ = ep.return_mapping(disc.material, disc.strain(u))
        u, U = project(u - rho * disc.internal_force(sigma) / d, disc, d, cols, rho)
        if iteration % check_every == 0:
            sigma, xi, _ = ep.return_mapping(disc.material, disc.strain(u))
            if ep.certify(disc, sigma, xi, disc.full_displacement(u), U).worst <= options.tol:
                break
            if options.time_limit is not None and time.perf_counter() - start > options.time_limit:
                break
    return disc.full_displacement(u), U


#: the same method with its own options: ``--method jacobi_uzawa:METHOD``, or the entry point
METHOD = ep.Method("jacobi-uzawa", run, JacobiOptions, "projected gradient on (D) in the Jacobi metric, fixed step")
