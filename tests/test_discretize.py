"""The assembled operators are the sums over elements they are defined as."""

from __future__ import annotations

import numpy as np

import elastoplast as ep
from conftest import build, cylinder_dict, sphere_quarter_dict


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


def test_derived_data_follows_the_inputs_it_is_built_from():
    """A new load or a path's step shares the mesh's derived data (nothing rebuilt, nothing
    copied by hand); a discretisation with other element volumes gets its own; a step keeps
    the obstacle itself, whatever its gap."""
    from dataclasses import replace

    disc = build(cylinder_dict(divisions=(8, 4)))
    layout = disc.layout
    other = disc.with_force(2 * disc.force)
    assert other.force == 2 * disc.force and other.shared is disc.shared and other.layout is layout
    u = np.random.default_rng(1).normal(size=disc.n_free) * 1e-3
    state = ep.Prestate.of(disc.material, np.zeros((disc.n_elements, disc.k)), np.zeros(disc.n_elements))
    step = disc.step(disc.force, state, u)
    assert step.shared is disc.shared and step.facet_topology is disc.facet_topology
    assert np.array_equal(step.psi, disc.psi + disc.N @ u) and step.base_psi is disc.base_psi
    assert disc.step(disc.force, state, 2 * u).base_psi is disc.base_psi  # from a step: still the obstacle
    scaled = replace(disc, volumes=2 * disc.volumes)
    assert scaled.shared is not disc.shared and scaled.layout is not layout


def test_element_edges_is_the_mesh_edge_table():
    """Each edge once as its sorted vertex pair, in lexicographic order, each element's local
    edges pointing at its own vertex pairs; Euler's formula V - E + F = 1 on a disc-like
    triangulation and V - E + F - T = 1 on a ball-like tetrahedral one."""
    from elastoplast.mesh.topology import element_edges, local_edges

    for data, euler in ((cylinder_dict(divisions=(20, 10)), 1), (sphere_quarter_dict(divisions=(3, 3, 2)), 1)):
        mesh = build(data).mesh
        cells = mesh.cells
        edges, element_edge = element_edges(cells, mesh.n_nodes)
        assert np.all(edges[:, 0] < edges[:, 1])
        assert np.all(np.diff(edges[:, 0] * mesh.n_nodes + edges[:, 1]) > 0)  # unique, lexicographic
        pairs = local_edges(mesh.dim)
        assert np.array_equal(edges[element_edge], np.sort(cells[:, pairs], axis=2))
        if mesh.dim == 2:
            assert mesh.n_nodes - len(edges) + len(cells) == euler
        else:
            from elastoplast.mesh.topology import element_facets, unique_rows

            faces = len(unique_rows(element_facets(cells)[0], mesh.n_nodes)[0])
            assert mesh.n_nodes - len(edges) + faces - len(cells) == euler
