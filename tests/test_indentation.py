"""Indentation figures (certificate/indentation.py) against Hertz's plane-strain contact on a graded half block.

A rigid cylinder of radius R on an elastic body, whole force F per unit length: half-width
b = sqrt(4 F R / (pi E*)), p0 = 2 F / (pi b), mean pressure F / (2 b) (Johnson, Contact Mechanics,
ch. 5). The model is the half x >= 0 with u_x = 0 on x = 0, so it carries F / 2.
"""

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("gmsh")

import elastoplast as ep
from elastoplast.fem.material import von_mises
from elastoplast.certificate.indentation import indentation_summary, surface_nodes, symmetry_share

E, NU, R, B = 200e3, 0.3, 40.0, 1.0
E_STAR = E / (1 - NU**2)
F = np.pi * E_STAR * B**2 / (4 * R)  # the Hertz half-width is B
P0 = 2 * F / (np.pi * B)
H_CONTACT = 0.05


def solve(yield_stress):
    problem = ep.problem_from_dict({
        "mesh": {"generator": "graded", "size": [20 * B, 20 * B], "contact_radius": 2 * B, "h_contact": H_CONTACT,
                 "h_far": 2.0},
        "material": {"E": E, "nu": NU, "yield_stress": yield_stress, "hardening": E / 10},
        "obstacle": {"shape": "cylinder", "radius": R},
        "load": {"force": F / 2},
    })
    disc = ep.discretize(problem)
    sol = ep.solve(disc, "conic")
    assert sol.converged and sol.kkt.worst < 1e-8
    return disc, sol


@pytest.fixture(scope="module")
def elastic():
    return solve(1e12)


def test_contact_radius_bracket_and_pressures_match_hertz(elastic):
    disc, sol = elastic
    out = indentation_summary(disc, sol)
    assert symmetry_share(disc) == out["symmetry_share"] == 0.5
    # the bracket is one contact element wide (h_contact, gmsh to 30 %) and holds b, up to the finite clamped
    # block's stiffening (5 % at 20 b, tests/test_hertz.py)
    lo, hi = out["contact_radius_active"], out["contact_radius_free"]
    assert 0 < hi - lo <= 1.3 * H_CONTACT
    assert lo <= B * 1.05 and hi >= B * 0.95
    # mean pressure: the whole force (twice the model's) over 2a, a the bracket's midpoint
    assert out["mean_contact_pressure"] == pytest.approx(F / (lo + hi), rel=1e-12)
    assert out["mean_contact_pressure"] == pytest.approx(np.pi * P0 / 4, rel=0.05)
    p_lo, p_hi = out["mean_contact_pressure_range"]
    assert p_lo < out["mean_contact_pressure"] < p_hi
    assert out["peak_contact_pressure"] == pytest.approx(P0, rel=0.05)
    assert out["plastic_zone_depth"] == out["plastic_zone_radius"] == 0.0


def test_surface_profile_is_sink_in_and_consistent_with_the_gap(elastic):
    disc, sol = elastic
    out = indentation_summary(disc, sol)
    # elastic: the free surface follows the indenter (u_d >= 0): no pile-up
    assert out["pile_up"] < 1e-9 * sol.U
    # at the outermost active node the gap is closed: u_d = U - psi(r), so u_d / U = 1 - psi / U
    r = disc.contact_radii()
    edge = np.argmax(np.where(sol.active, r, -1.0))
    psi = R - np.sqrt(R**2 - r[edge] ** 2)
    assert out["sink_in_at_edge"] == pytest.approx(1 - psi / sol.U, rel=1e-6)
    a = 0.5 * (out["contact_radius_active"] + out["contact_radius_free"])
    assert out["contact_depth_ratio"] == pytest.approx(a * a / (2 * R * sol.U), rel=1e-12)
    # the surface: every node on y = 0, the contact zone's among them
    nodes = surface_nodes(disc)
    assert np.all(disc.mesh.points[nodes, 1] == 0.0) and np.isin(disc.contact_nodes, nodes).all()
    assert np.isclose(disc.mesh.points[nodes, 0].max(), 20 * B)


def test_grazing_node_is_free():
    disc, sol = solve(1e12)
    lam = sol.contact_force.copy()
    r = disc.contact_radii()
    beyond = np.flatnonzero(~sol.active)[np.argmin(r[~sol.active])]
    lam[beyond] = 1e-9 * lam.max()
    out = indentation_summary(disc, replace(sol, active=lam > 1e-4 * lam.max(), contact_force=lam))
    assert out["contact_radius_free"] == pytest.approx(r[beyond])


def test_plastic_zone_holds_the_elastic_maximum(elastic):
    # the onset read off the elastic solution itself: with sigma_y 2 % above its largest von Mises stress
    # nothing yields; 3 % below it, the element of the maximum (below the surface, as in Hertz's field)
    # yields and bounds the zone's depth and radius from below
    disc, sol = elastic
    vm = von_mises(sol.sigma)
    top = disc.mesh.points[disc.mesh.cells[np.argmax(vm)]].mean(axis=0)
    assert 0.3 * B < top[1] < B
    assert indentation_summary(*solve(1.02 * vm.max()))["plastic_zone_depth"] == 0.0
    disc, sol = solve(0.97 * vm.max())
    out = indentation_summary(disc, sol)
    centroids = disc.mesh.points[disc.mesh.cells[sol.plastic]].mean(axis=1)
    assert out["plastic_zone_depth"] == centroids[:, 1].max() >= top[1]
    assert out["plastic_zone_radius"] == np.abs(centroids[:, 0]).max() >= top[0]
    assert centroids[:, 1].min() > 0.1 * B  # the zone starts below the surface


def test_path_summary_holds_oliver_pharr_of_the_whole_force(tmp_path):
    # a quarter block (share 1/4) loaded and unloaded elastically: the path's Oliver-Pharr record is the
    # analysis of its own (U, 4 F) points, and its plot draws
    from elastoplast.certificate.oliver_pharr import oliver_pharr
    from elastoplast.plots.figures import plot_path
    from elastoplast.io.loading_path import path_summary

    forces = [100.0, 200.0, 170.0, 140.0, 110.0]
    problem = ep.problem_from_dict({
        "mesh": {"generator": "graded", "size": [6.0, 6.0, 6.0], "contact_radius": 1.5, "h_contact": 0.4, "h_far": 2.0},
        "material": {"E": E, "nu": NU, "yield_stress": 1e12, "hardening": E / 10},
        "obstacle": {"shape": "paraboloid", "radius": 20.0}, "load": {"path": forces}})
    disc = ep.discretize(problem)
    result = ep.solve_path(disc, problem.path, "conic")
    record = path_summary(disc, result)
    op = record["oliver_pharr"]
    assert op["force_share"] == record["indentation"]["symmetry_share"] == 0.25
    again = oliver_pharr([0.0] + [s.U for s in result.steps], [0.0] + [4 * f for f in forces], shape="paraboloid",
                         E=E, nu=NU, radius=20.0)
    assert op["S"] == again["S"] and op["F_max"] == 800.0 and op["step_peak"] == 2
    assert op["E_star"] == pytest.approx(E_STAR)
    # the indentation figures after the last step are those of its force (110, the model's), not the path's
    # largest (200): p_m = 4 * 110 / (pi a^2), a the midpoint of the last step's bracket
    ind = record["indentation"]
    a = 0.5 * (ind["contact_radius_active"] + ind["contact_radius_free"])
    assert ind["mean_contact_pressure"] == pytest.approx(4 * forces[-1] / (np.pi * a * a), rel=1e-12)
    plot_path(tmp_path / "path.png", record)
    assert (tmp_path / "path.png").stat().st_size > 0


def test_axisymmetric_sphere_matches_hertz_and_writes_the_revolved_view(tmp_path):
    # a rigid sphere on the meridian plane of a cylinder 20 a wide: a = (3 F R / (4 E*))^(1/3) (chosen = 1),
    # p0 = 3 F / (2 pi a^2), p_m = F / (pi a^2), U = a^2 / R and u_z = U / 2 at the edge (Johnson, ch. 4)
    import meshio

    from elastoplast.studies.results import write_files

    radius = 40.0
    force = 4 * E_STAR / (3 * radius)
    problem = ep.problem_from_dict({
        "mesh": {"axisymmetric": True, "generator": "graded", "size": [20.0, 20.0], "contact_radius": 2.0,
                 "h_contact": H_CONTACT, "h_far": 2.0},
        "material": {"E": E, "nu": NU, "yield_stress": 1e12, "hardening": E / 10},
        "obstacle": {"shape": "sphere", "radius": radius}, "load": {"force": force}})
    assert dict(problem.boundary.fix_component) == {}  # the axis holds u_r = 0 by itself
    disc = ep.discretize(problem)
    sol = ep.solve(disc, "conic")
    assert sol.converged
    data = write_files(tmp_path, disc, sol)
    out = data["indentation"]
    lo, hi = out["contact_radius_active"], out["contact_radius_free"]
    assert out["symmetry_share"] == 1.0 and lo <= 1.0 <= hi and hi - lo <= 1.3 * H_CONTACT
    assert out["mean_contact_pressure"] == pytest.approx(force / (np.pi * 0.25 * (lo + hi) ** 2), rel=1e-12)
    assert out["mean_contact_pressure"] == pytest.approx(force / np.pi, rel=0.05)
    assert out["peak_contact_pressure"] == pytest.approx(3 * force / (2 * np.pi), rel=0.05)
    assert out["sink_in_at_edge"] == pytest.approx(0.5, rel=0.05)
    assert out["contact_depth_ratio"] == pytest.approx(0.5, rel=0.1)
    # the revolved view: its volume is the polygonal revolution's, n sin(2 pi / n) sum |T| r_T
    view = meshio.read(tmp_path / "solution_3d.vtu")
    n = data["revolved_view"]["sectors"]
    X = disc.mesh.points[disc.mesh.cells]
    area = 0.5 * np.abs(np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)))
    from elastoplast.io.revolve import cell_volumes
    blocks = {c.type: (c.data, None) for c in view.cells}
    assert cell_volumes(view.points, blocks).sum() == pytest.approx(
        n * np.sin(2 * np.pi / n) * float(area @ X[:, :, 0].mean(axis=1)), rel=1e-10)
    assert set(view.cell_data) >= {"stress", "von_mises", "xi", "plastic"}
