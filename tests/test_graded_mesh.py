"""The graded indentation generator (elastoplast/mesh/graded.py) and its [mesh] table."""

import numpy as np
import pytest

pytest.importorskip("gmsh")

from elastoplast.errors import InputError
from elastoplast.mesh.graded import graded_mesh
from elastoplast.problem.definition import problem_from_dict


def volumes(mesh):
    X = mesh.points[mesh.cells]
    return np.abs(np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))) / (2 if mesh.dim == 2 else 6)


def measure(mesh, name):
    f = mesh.points[mesh.groups[name]]
    if mesh.dim == 2:
        return np.linalg.norm(f[:, 1] - f[:, 0], axis=1).sum()
    return 0.5 * np.linalg.norm(np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0]), axis=1).sum()


def test_meridian_rectangle_exact_contact_edge_and_few_elements():
    # a block 20 contact radii wide: its area and the contact segment's length are exact (straight edges),
    # and h_contact = c/40 needs a few thousand triangles (a tensor grid at that spacing: 2 * 800^2)
    mesh = graded_mesh([20.0, 20.0], 1.0, 0.025, 2.0)
    assert volumes(mesh).sum() == pytest.approx(400.0, rel=1e-12)
    assert measure(mesh, "contact") == pytest.approx(1.0, rel=1e-12)
    assert measure(mesh, "bottom") == pytest.approx(19.0, rel=1e-12)
    assert measure(mesh, "xmin") == measure(mesh, "top") == pytest.approx(20.0, rel=1e-12)
    assert mesh.n_elements < 5000
    # fine at the contact: every contact facet no longer than h_contact (gmsh's size to 30 %)
    f = mesh.points[mesh.groups["contact"]]
    assert np.linalg.norm(f[:, 1] - f[:, 0], axis=1).max() <= 1.3 * 0.025
    # coarse far away: the top's edges are near h_far
    t = mesh.points[mesh.groups["top"]]
    assert np.linalg.norm(t[:, 1] - t[:, 0], axis=1).min() > 1.0


def test_quarter_block_exact_quarter_disc():
    c = 1.0
    mesh = graded_mesh([8.0, 8.0, 8.0], c, 0.2, 2.0)
    assert volumes(mesh).sum() == pytest.approx(512.0, rel=1e-12)
    # the quarter disc's polygon: area below pi c^2 / 4 by the chord error, at most (h/c)^2 / 8 relative... within 1 %
    area = measure(mesh, "contact")
    assert area < np.pi / 4 and area == pytest.approx(np.pi / 4, rel=1e-2)
    assert area + measure(mesh, "bottom") == pytest.approx(64.0, rel=1e-12)
    r = np.linalg.norm(mesh.points[mesh.groups["contact"]][:, :, :2], axis=2)
    assert r.max() <= c * (1 + 1e-9)
    assert set(mesh.groups) == {"xmin", "xmax", "ymin", "ymax", "top", "bottom", "contact"}


def problem(**mesh):
    section = {"generator": "graded", "size": [20.0, 20.0], "contact_radius": 2.0, "h_contact": 0.2, "h_far": 2.0}
    section.update(mesh)
    return {"mesh": {k: v for k, v in section.items() if v is not None},
            "material": {"E": 200000.0, "nu": 0.3, "yield_stress": 400.0, "hardening": 1000.0},
            "obstacle": {"shape": "sphere", "radius": 100.0}, "load": {"force": 10.0}}


def test_problem_file_graded_symmetry_planes_by_default():
    p = problem_from_dict(problem())
    assert p.boundary.clamped == ("xmax", "top")
    assert dict(p.boundary.fix_component) == {0: ("xmin",)}
    p3 = problem_from_dict(problem(size=[6.0, 6.0, 6.0], contact_radius=1.0, h_contact=0.3))
    assert dict(p3.boundary.fix_component) == {0: ("xmin",), 1: ("ymin",)}
    assert set(p3.boundary.clamped) == {"xmax", "ymax", "top"}


@pytest.mark.parametrize("change, field", [
    ({"h_contact": None}, "mesh.h_contact"),
    ({"h_contact": 3.0}, "mesh.h_contact"),
    ({"h_contact": -1.0}, "mesh.h_contact"),
    ({"h_far": 0.1}, "mesh.h_far"),
    ({"h_far": 50.0}, "mesh.h_far"),
    ({"contact_radius": 30.0}, "mesh.contact_radius"),
    ({"contact_radius": float("nan")}, "mesh.contact_radius"),
    ({"size": [1.0, 2.0, 3.0]}, "mesh.size"),
    ({"size": [0.0, 2.0]}, "mesh.size"),
    ({"divisions": [4, 4]}, "mesh.divisions"),
    ({"h_contact": 1e-5}, "mesh.h_contact"),
])
def test_bad_graded_settings_name_the_field(change, field):
    with pytest.raises(InputError) as info:
        problem_from_dict(problem(**change))
    assert info.value.field == field


def test_structured_generator_refuses_graded_keys():
    data = problem()
    data["mesh"] = {"generator": "rectangle", "size": [4.0, 2.0], "divisions": [4, 2], "contact_radius": 1.0,
                    "h_far": 1.0}
    with pytest.raises(InputError) as info:
        problem_from_dict(data)
    assert info.value.field == "mesh.h_far"
