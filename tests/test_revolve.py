"""The revolved 3D view of a meridian mesh (io/revolve.py): volumes of revolution, fields, the cap."""

import math

import meshio
import numpy as np
import pytest

from elastoplast.errors import InputError
from elastoplast.io.revolve import MIN_SECTORS, cell_volumes, orient, revolve_mesh, sectors_for, write_revolved_vtu
from elastoplast.mesh.base import structured_mesh


def meridian(origin_x):
    """A crossed-pattern rectangle [x0, x0 + 2] x [0, 1]: on the axis when x0 = 0."""
    return structured_mesh([2.0, 1.0], [6, 4], 0.5, origin=[origin_x, 0.0], contact_center=[origin_x], pattern="crossed")


def pappus(mesh):
    """sum_T |T| r_T: 2 pi times it is the body of revolution's volume (Pappus)."""
    X = mesh.points[mesh.cells]
    area = 0.5 * np.abs(np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)))
    return float(area @ X[:, :, 0].mean(axis=1))


@pytest.mark.parametrize("x0, kinds", [(0.0, {"wedge", "pyramid", "tetra"}), (1.0, {"wedge"})])
@pytest.mark.parametrize("n", [8, 36, 720])
def test_volume_is_the_polygonal_revolution(x0, kinds, n):
    mesh = meridian(x0)
    points3, blocks, _, _ = revolve_mesh(mesh.points, mesh.cells, n)
    assert set(blocks) == kinds
    # planar side faces: each cell's volume is sin(2 pi / n) |T| r_T exactly
    vol = cell_volumes(points3, blocks).sum()
    assert vol == pytest.approx(n * math.sin(2 * math.pi / n) * pappus(mesh), rel=1e-12)
    # and the view tends to the body of revolution: relative error (2 pi / n)^2 / 6
    assert abs(vol / (2 * math.pi * pappus(mesh)) - 1) <= (2 * math.pi / n) ** 2 / 6 * 1.001
    # every cell within the sector's angles, every sector's cells as many as the triangles
    assert sum(c.shape[0] for c, _ in blocks.values()) == n * mesh.n_elements


def test_oriented_cells_have_positive_volume():
    mesh = meridian(0.0)
    points3, blocks, _, _ = revolve_mesh(mesh.points, mesh.cells, 12)
    for kind, (conn, _) in orient(points3, blocks).items():
        X = points3[conn]
        if kind == "tetra":
            assert np.all(np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)) > 0)
        elif kind == "wedge":
            normal = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
            assert np.all(np.einsum("ij,ij->i", normal, X[:, 3] - X[:, 0]) > 0)


def test_fields_are_carried_and_turned(tmp_path):
    mesh = meridian(0.0)
    u = np.column_stack([mesh.points[:, 0], -mesh.points[:, 1]])  # u_r = r, u_z = -z
    path = tmp_path / "solution_3d.vtu"
    n = write_revolved_vtu(path, mesh.points, mesh.cells, point_data={"displacement": u, "p": mesh.points[:, 1]},
                           cell_data={"id": np.arange(mesh.n_elements)}, n_sectors=16)
    out = meshio.read(path)
    assert n == 16
    disp = out.point_data["displacement"]
    # u_r = r turned with the node: (x, y) in the plane, u_z = -z
    assert np.allclose(disp[:, :2], out.points[:, :2]) and np.allclose(disp[:, 2], -out.points[:, 2])
    assert np.allclose(out.point_data["p"], out.points[:, 2])
    ids = np.concatenate(out.cell_data["id"])
    assert np.array_equal(np.bincount(ids), np.full(mesh.n_elements, 16))


def test_cap_lowers_the_sectors_and_refuses_beyond():
    assert sectors_for(1000, 36, max_cells=20_000) == 20
    with pytest.raises(InputError) as info:
        sectors_for(1000, 36, max_cells=1000 * (MIN_SECTORS - 1))
    assert info.value.field == "n_sectors"
    with pytest.raises(InputError):
        sectors_for(10, 3)
    with pytest.raises(InputError) as info:
        revolve_mesh(np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]]), 8)
    assert info.value.field == "mesh"
