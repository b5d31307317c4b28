"""The assembled operators are the sums over elements they are defined as."""

from __future__ import annotations

import numpy as np

from conftest import build, sphere_quarter_dict


def test_weighted_gram_is_the_element_sum():
    disc = build(sphere_quarter_dict(divisions=(3, 3, 2)))
    v = np.random.default_rng(0).normal(size=disc.n_free)
    eps = disc.strain(v)
    C = disc.material.stiffness(disc.dim)
    # v^T (sum_T |T| B_T^T M B_T) v = sum_T |T| eps_T M eps_T, by definition
    for M in (np.eye(disc.k), C):
        assert np.isclose(v @ disc.weighted_gram(M) @ v, np.einsum("e,ei,ij,ej->", disc.volumes, eps, M, eps))
    # one shared block and the same block given per element assemble the same matrix
    per_element = np.broadcast_to(C, (disc.n_elements,) + C.shape)
    assert abs(disc.weighted_gram(C) - disc.weighted_gram(per_element)).max() <= 1e-12 * abs(disc.weighted_gram(C)).max()
