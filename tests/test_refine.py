"""Conforming bisection refinement and Dörfler marking (issue 11, part 1).

What is checked and where the expected values come from:

* conformity: every facet met by one element lies on the boundary (their total
  measure equals the boundary measure of the input mesh, which refinement does
  not change), no facet is met by three, and no node sits at the midpoint of an
  edge (a bisection mesh with a hanging node has one there);
* volumes: the children of an element fill it (sum of |T| per parent equals
  the parent's |T|), all elements positively oriented, ``discretize`` accepts
  the refined mesh;
* facet groups: same measure, facets are boundary facets lying inside the
  facets they came from, the contact group stays in x_d = 0 exactly;
* uniform refinement: d bisections per element give 2^d children, and on Kuhn
  simplices (right isosceles triangles, cube-path tetrahedra) of half the
  diameter, which is Maubach's theorem;
* shapes: on the structured meshes every descendant is similar to an element of
  the first d generations (Maubach: the Kuhn cycle repeats after d bisections;
  in 2D newest-vertex bisection gives at most 4 classes per triangle, Mitchell);
* marking: Dörfler's set is monotone in theta and in the indicator value, and
  minimal;
* a problem on a refined mesh solves and certifies.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from conftest import build, cylinder_dict, sphere_quarter_dict
from elastoplast.mesh.refinement import dorfler_mark, initial_state, prolong_p1, refine, shape_quality, signed_volumes

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"


# ----------------------------------------------------------------------------
# meshes
# ----------------------------------------------------------------------------


def gmsh_box(path: Path) -> ep.Mesh:
    """An unstructured tetrahedral block with a disc-shaped contact group, made
    by gmsh with the generator of the side study benchmarks/adapt/refine.py."""
    pytest.importorskip("gmsh")
    spec = importlib.util.spec_from_file_location("adapt_refine", ROOT / "benchmarks" / "adapt" / "refine.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    return study.gmsh_box(0.4, path)


MESHES = ["rectangle", "crossed", "punch_gmsh", "box", "quarter", "box_gmsh"]


@pytest.fixture(scope="module", params=MESHES)
def mesh(request, tmp_path_factory) -> ep.Mesh:
    name = request.param
    if name == "rectangle":
        return ep.structured_mesh([8.0, 4.0], [8, 4], 1.0, grading=1.5)
    if name == "crossed":
        return ep.structured_mesh([8.0, 4.0], [6, 3], 1.0, grading=1.3, pattern="crossed")
    if name == "punch_gmsh":
        return ep.read_mesh(PROBLEMS / "punch_2d.msh")
    if name == "box":
        return ep.structured_mesh([6.0, 6.0, 3.0], [4, 4, 3], 1.5, grading=1.6)
    if name == "quarter":
        return ep.structured_mesh([3.0, 3.0, 3.0], [3, 3, 3], 1.5, origin=[0.0, 0.0, 0.0], grading=1.6)
    return gmsh_box(tmp_path_factory.mktemp("gmsh") / "box.msh")


# ----------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------


def measure(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    X = points[facets]
    if facets.shape[1] == 2:
        return np.linalg.norm(X[:, 1] - X[:, 0], axis=1)
    return 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)


def area_vectors(points: np.ndarray, facets: np.ndarray) -> np.ndarray:
    X = points[facets]
    if facets.shape[1] == 2:
        return X[:, 1] - X[:, 0]
    return 0.5 * np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])


def facet_counts(mesh: ep.Mesh) -> tuple[np.ndarray, np.ndarray]:
    d = mesh.dim
    faces = np.sort(np.concatenate([np.delete(mesh.cells, i, axis=1) for i in range(d + 1)]), axis=1)
    return np.unique(faces, axis=0, return_counts=True)


def boundary_measure(mesh: ep.Mesh) -> float:
    faces, counts = facet_counts(mesh)
    return float(measure(mesh.points, faces[counts == 1]).sum())


def assert_conforming(new: ep.Mesh, old: ep.Mesh) -> None:
    faces, counts = facet_counts(new)
    assert counts.max() <= 2
    # a facet met once is on the boundary: the boundary measure is unchanged
    np.testing.assert_allclose(measure(new.points, faces[counts == 1]).sum(), boundary_measure(old), rtol=1e-12)
    # no hanging node: no node at the midpoint of an edge
    d = new.dim
    edges = np.unique(np.sort(np.concatenate([new.cells[:, [i, j]] for i in range(d + 1) for j in range(i)]), axis=1), axis=0)
    mid = 0.5 * (new.points[edges[:, 0]] + new.points[edges[:, 1]])
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(new.points).query(mid)
    shortest = np.linalg.norm(new.points[edges[:, 0]] - new.points[edges[:, 1]], axis=1).min()
    assert dist.min() > 0.25 * shortest


def assert_children_fill_parents(new: ep.Mesh, old: ep.Mesh, parent: np.ndarray) -> None:
    vol_new, vol_old = signed_volumes(new.points, new.cells), np.abs(signed_volumes(old.points, old.cells))
    assert np.all(vol_new > 0)
    # to rounding: coordinates of size |x| carry errors ~1e-16 |x|, which move a
    # volume of diameter h by ~1e-16 |x| h^(d-1)
    filled = np.bincount(parent, weights=vol_new, minlength=old.n_elements)
    scale = np.abs(old.points).max()
    assert np.all(np.abs(filled - vol_old) <= 1e-12 * vol_old + 1e-13 * scale * diameters(old) ** (old.dim - 1))
    # each child lies inside its parent: its centroid has positive barycentric coordinates there
    X = old.points[old.cells[parent]]
    c = new.points[new.cells].mean(axis=1)
    lam = np.linalg.solve(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2), (c - X[:, 0])[:, :, None])[:, :, 0]
    assert np.all(lam > -1e-12) and np.all(lam.sum(axis=1) < 1 + 1e-12)


def inside_some(p: np.ndarray, facet_points: np.ndarray, tol: float) -> np.ndarray:
    """Whether each point lies in one of the facets (segments or triangles):
    its projection has non-negative barycentric coordinates and it is within
    ``tol`` of the facet's line or plane."""
    a = facet_points[:, 0]
    E = facet_points[:, 1:] - a[:, None]  # (nf, d-1, d)
    Ginv = np.linalg.inv(np.einsum("fid,fjd->fij", E, E))
    ok = np.zeros(p.shape[0], dtype=bool)
    for f in range(a.shape[0]):  # one facet at a time: all points against it
        r = p - a[f]
        lam = (r @ E[f].T) @ Ginv[f]
        off = np.linalg.norm(r - lam @ E[f], axis=1)
        ok |= (off <= tol) & np.all(lam >= -1e-9, axis=1) & (lam.sum(axis=1) <= 1 + 1e-9)
    return ok


def assert_groups_refined(new: ep.Mesh, old: ep.Mesh, *, inside: bool = True) -> None:
    assert set(new.groups) == set(old.groups)
    faces, counts = facet_counts(new)
    boundary = {tuple(f) for f in faces[counts == 1]}
    size = np.max(old.points.max(axis=0) - old.points.min(axis=0))
    for name, facets in new.groups.items():
        before = old.groups[name]
        np.testing.assert_allclose(measure(new.points, facets).sum(), measure(old.points, before).sum(), rtol=1e-12)
        assert all(tuple(f) in boundary for f in np.sort(facets, axis=1))
        # children lie in the facets they refine, oriented like them: the sums
        # of the area vectors (2D: of the tangents) agree
        if inside:
            assert np.all(inside_some(new.points[np.unique(facets)], old.points[before], 1e-12 * size))
        np.testing.assert_allclose(area_vectors(new.points, facets).sum(axis=0), area_vectors(old.points, before).sum(axis=0),
                                   atol=1e-12 * measure(old.points, before).sum())
    if "contact" in new.groups:
        assert np.all(new.points[new.groups["contact"], -1] == 0.0)


def near_contact(mesh: ep.Mesh, node: int | None = None) -> np.ndarray:
    """The elements around the node closest to the contact centre (the origin)."""
    if node is None:
        node = int(np.argmin(np.linalg.norm(mesh.points, axis=1)))
    return np.any(mesh.cells == node, axis=1)


# ----------------------------------------------------------------------------
# refinement
# ----------------------------------------------------------------------------


def test_local_refinement_conforms_and_keeps_groups(mesh):
    rng = np.random.default_rng(0)
    current, state = mesh, initial_state(mesh)
    for step in range(3):
        marked = near_contact(current) | (rng.random(current.n_elements) < 0.05)
        new, new_state, parent = refine(current, marked, state)
        # marked elements are bisected d times, the closure bisects the others 0 or more times
        assert np.all(new_state.generation - state.generation[parent] >= np.where(marked[parent], current.dim, 0))
        state = new_state
        assert_conforming(new, current)
        assert_children_fill_parents(new, current, parent)
        assert_groups_refined(new, current, inside=False)
        np.testing.assert_array_equal(new.points[: current.n_nodes], current.points)  # old nodes keep their numbers
        current = new
    assert_groups_refined(current, mesh)


def test_uniform_refinement_multiplies_by_2_to_the_d(mesh):
    """d bisections of every element: 4 triangles or 8 tetrahedra each, all edges
    of the input mesh bisected once (each face is bisected by newest-vertex
    bisection from its marked edge, so no closure is needed)."""
    new, _, parent = refine(mesh, np.ones(mesh.n_elements, dtype=bool))
    assert new.n_elements == 2**mesh.dim * mesh.n_elements
    np.testing.assert_array_equal(np.bincount(parent), np.full(mesh.n_elements, 2**mesh.dim))
    d = mesh.dim
    edges = {tuple(e) for e in np.sort(np.concatenate([mesh.cells[:, [i, j]] for i in range(d + 1) for j in range(i)]), axis=1)}
    assert new.n_nodes == mesh.n_nodes + len(edges)
    assert_conforming(new, mesh)


def diameters(mesh: ep.Mesh) -> np.ndarray:
    X = mesh.points[mesh.cells]
    d = mesh.dim
    return np.max([np.linalg.norm(X[:, i] - X[:, j], axis=1) for i in range(d + 1) for j in range(i)], axis=0)


@pytest.mark.parametrize("kind", ["rectangle", "crossed", "box"])
def test_uniform_refinement_halves_kuhn_simplices(kind):
    """Maubach: d bisections of a Kuhn simplex give Kuhn simplices of half the
    size; repeated, the count grows by 2^d per level with no closure."""
    mesh = {"rectangle": ep.structured_mesh([8.0, 4.0], [8, 4], 1.0, grading=1.5),
            "crossed": ep.structured_mesh([8.0, 4.0], [6, 3], 1.0, pattern="crossed"),  # squares: right isosceles triangles
            "box": ep.structured_mesh([6.0, 6.0, 3.0], [3, 3, 2], 1.5, grading=1.6)}[kind]
    current, state, ancestor = mesh, None, np.arange(mesh.n_elements)
    h0 = diameters(mesh)
    for level in (1, 2):
        current, state, parent = refine(current, np.ones(current.n_elements, dtype=bool), state)
        ancestor = ancestor[parent]
        assert current.n_elements == 2 ** (mesh.dim * level) * mesh.n_elements
        np.testing.assert_allclose(diameters(current), h0[ancestor] / 2**level, rtol=1e-12)
    assert_conforming(current, mesh)


def test_structured_shapes_repeat_after_d_bisections():
    """On Kuhn meshes every descendant is similar to an element of generations
    0..d-1 of its own ancestor (Maubach); twenty rounds of refinement at the
    contact centre therefore produce no shape outside that finite set."""
    for mesh in (ep.structured_mesh([6.0, 6.0, 3.0], [3, 3, 2], 1.5, grading=1.6),
                 ep.structured_mesh([8.0, 4.0], [6, 3], 1.0, grading=1.3, pattern="crossed")):
        d = mesh.dim
        classes, layer, s = [shape_quality(mesh)], mesh, None
        for _ in range(d - 1):
            layer, s, _ = refine(layer, np.ones(layer.n_elements, dtype=bool), s, bisections=1)
            classes.append(shape_quality(layer))
        known = np.concatenate(classes)
        current, state = mesh, None
        for _ in range(20):
            current, state, _ = refine(current, near_contact(current), state)
        assert state.generation.max() == 20 * d
        q = shape_quality(current)
        gap = np.min(np.abs(q[:, None] - np.unique(known)[None]), axis=1)
        assert gap.max() < 1e-9
        assert q.min() >= known.min() - 1e-12


def test_unstructured_shapes_stay_bounded(mesh):
    """Finitely many similarity classes per initial element (newest-vertex
    bisection in 2D; Arnold-Mukherjee-Pouly / Maubach in 3D): twenty rounds
    concentrated at one node reach generation 20 d, and the worst shape is no
    worse than the worst among the first 2 d generations of the bisection
    forest of the same mesh."""
    d = mesh.dim
    worst, layer, s = shape_quality(mesh).min(), mesh, None
    for _ in range(2 * d):
        layer, s, _ = refine(layer, np.ones(layer.n_elements, dtype=bool), s, bisections=1)
        worst = min(worst, shape_quality(layer).min())
    current, state = mesh, None
    centre = int(np.argmin(np.linalg.norm(mesh.points, axis=1)))  # an input node: never moves
    for _ in range(20):
        current, state, _ = refine(current, near_contact(current, centre), state)
    assert state.generation.max() == 20 * d
    assert shape_quality(current).min() >= worst - 1e-12


def test_nothing_marked_is_the_same_mesh(mesh):
    new, state, parent = refine(mesh, np.zeros(mesh.n_elements, dtype=bool))
    np.testing.assert_array_equal(new.points, mesh.points)
    np.testing.assert_array_equal(parent, np.arange(mesh.n_elements))
    np.testing.assert_array_equal(np.sort(new.cells, axis=1), np.sort(mesh.cells, axis=1))
    assert np.all(state.generation == 0)


def test_prolong_p1_is_exact_for_affine_fields():
    """P1 interpolation reproduces affine functions: at every new node the
    prolonged value is the function's value."""
    mesh = ep.structured_mesh([6.0, 6.0, 3.0], [3, 3, 2], 1.5, grading=1.6)
    f = lambda x: 1.5 + x @ np.array([0.3, -2.0, 0.7])  # noqa: E731
    current, state = mesh, None
    for _ in range(3):
        current, state, _ = refine(current, near_contact(current), state)
    values = prolong_p1(state, f(mesh.points))
    np.testing.assert_allclose(values, f(current.points), rtol=0, atol=1e-13)
    both = prolong_p1(state, np.stack([f(mesh.points), 2 * f(mesh.points)], axis=1))
    np.testing.assert_allclose(both[:, 1], 2 * values, rtol=1e-15)


def test_bad_input_is_refused():
    mesh = ep.structured_mesh([2.0, 1.0], [4, 2], 0.5)
    with pytest.raises(ep.InputError, match="marked"):
        refine(mesh, np.ones(3, dtype=bool))
    with pytest.raises(ep.InputError, match="marked"):
        refine(mesh, np.array([0, mesh.n_elements]))
    with pytest.raises(ep.InputError, match="bisections"):
        refine(mesh, [0], bisections=0)
    other = ep.structured_mesh([2.0, 1.0], [2, 2], 0.5)
    with pytest.raises(ep.InputError, match="state"):
        refine(mesh, [0], initial_state(other))
    with pytest.raises(ep.InputError, match="mesh.groups.top"):
        refine(dataclasses.replace(mesh, groups={**mesh.groups, "top": mesh.cells}), [0])
    with pytest.raises(ep.InputError, match="zero volume"):
        refine(dataclasses.replace(mesh, cells=np.array([[0, 1, 2]])), [0])


# ----------------------------------------------------------------------------
# Dörfler marking
# ----------------------------------------------------------------------------


def test_dorfler_marking_is_monotone_and_minimal():
    rng = np.random.default_rng(3)
    eta = rng.exponential(size=500) ** 2
    eta[:20] = eta[20]  # ties
    eta[-5:] = 0.0
    previous = np.zeros(eta.size, dtype=bool)
    for theta in np.linspace(0.0, 1.0, 41):
        m = dorfler_mark(eta, theta)
        assert np.all(m[previous])  # larger theta: a superset
        if m.any():
            assert eta[~m].max(initial=0.0) < eta[m].min()  # no smaller one marked over a larger one
            assert eta[m].sum() >= theta * eta.sum() * (1 - 1e-15)
            # minimal: without its smallest indicator value the set falls short
            smallest = eta[m] == eta[m].min()
            assert eta[m][~smallest].sum() < theta * eta.sum()
        previous = m
    assert not dorfler_mark(eta, 0.0).any()
    np.testing.assert_array_equal(dorfler_mark(eta, 1.0), eta > 0)
    np.testing.assert_array_equal(dorfler_mark(np.array([1.0, 3.0, 2.0]), 0.5), [False, True, False])
    np.testing.assert_array_equal(dorfler_mark(np.array([1.0, 3.0, 2.0]), 0.51), [False, True, True])


@pytest.mark.parametrize("eta,theta,field", [
    (np.array([1.0, np.nan]), 0.5, "indicators"),
    (np.array([1.0, -1e-3]), 0.5, "indicators"),
    (np.array([1.0, np.inf]), 0.5, "indicators"),
    (np.ones((2, 2)), 0.5, "indicators"),
    (np.ones(3), 1.5, "theta"),
    (np.ones(3), float("nan"), "theta"),
])
def test_dorfler_refuses_bad_input(eta, theta, field):
    with pytest.raises(ep.InputError) as err:
        dorfler_mark(eta, theta)
    assert err.value.field == field


# ----------------------------------------------------------------------------
# solving on refined meshes
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("data", [cylinder_dict(), sphere_quarter_dict(divisions=(4, 4, 4))], ids=["cylinder_2d", "quarter_3d"])
def test_problem_on_refined_mesh_certifies(data):
    """Refine near the contact zone twice (the quarter model keeps its symmetry
    planes x = 0, y = 0 as groups) and solve: discretize accepts the mesh, the
    contact nodes lie in x_d = 0, Newton converges and the KKT certificate of the
    refined problem holds."""
    disc = build(copy.deepcopy(data))
    problem, state = disc.problem, None
    for _ in range(2):
        mesh = problem.mesh
        contact = mesh.group_nodes(["contact"])
        marked = np.any(np.isin(mesh.cells, contact), axis=1)
        new_mesh, state, _ = refine(mesh, marked, state)
        problem = dataclasses.replace(problem, mesh=new_mesh)
    for name, axis in (("xmin", 0), ("ymin", 1)):
        if name in problem.mesh.groups and problem.mesh.dim == 3:
            assert np.all(problem.mesh.points[problem.mesh.groups[name], axis] == 0.0)
    refined = ep.discretize(problem)
    assert refined.n_contact > disc.n_contact and refined.n_elements > disc.n_elements
    sol = ep.solve(refined, "newton", tol=1e-10)
    assert sol.converged, sol.message
    assert sol.kkt.worst <= 1e-10
