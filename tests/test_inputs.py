"""Faithful input (issue 9): hostile and edge inputs, class by class.

Each case writes the exact input into ``tmp_path`` and runs the command line
``main(["solve", ...])``: a bad input must end in exit code 2 with exactly one
``error:`` line naming the field and no traceback; an input that is legal but was
repaired or is questionable is solved with a ``warning:`` line saying so. Unit tests
of the checks themselves follow each class.
"""

from __future__ import annotations

import contextlib
import os
import time
import tracemalloc
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest

import elastoplast as ep
from elastoplast.limits import (MEMORY_ENV, available_memory, mesh_read_bytes, discretization_bytes, parse_bytes,
    structured_counts)
from elastoplast.mesh.checks import check_conforming
from elastoplast.fem.locking import check_perfect_plasticity, crossed_centres
from elastoplast.cli.main import main
from elastoplast.errors import InputError

from test_cli import small_cylinder, write_toml


def solve_cli(tmp_path: Path, problem: Path) -> int:
    return main(["solve", str(problem), "--out", str(tmp_path / "out"), "--quiet"])


def assert_refused(code: int, err: str, field: str, *words: str) -> str:
    """Exit 2, one ``error:`` line, naming ``field`` (and saying ``words``); returns the line."""
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"error: {field}:"), lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def refused(tmp_path, capsys, data: dict, field: str, *words: str) -> str:
    code = solve_cli(tmp_path, write_toml(tmp_path / "p.toml", data))
    return assert_refused(code, capsys.readouterr().err, field, *words)


# ============================================================================
# 1. problem files
# ============================================================================

PROBLEM_BYTES = {
    "not UTF-8 (Latin-1 comment)": (b"[load]\nforce = 1.0  # caf\xe9\n", "not UTF-8"),
    "not UTF-8 (Latin-1 value)": (b'[mesh]\ngenerator = "rect\xe9ngle"\n', "not UTF-8"),
    "UTF-16": ("[load]\nforce = 1.0\n".encode("utf-16"), "UTF-16"),
    "binary garbage": (bytes(range(256)) * 8, "not UTF-8"),
    "empty": (b"", "empty"),
    "only comments": (b"# nothing here\n\n", "no settings"),
    "NUL byte": (b"[mesh]\x00\n", "not valid TOML"),
    "nesting too deep": (b"a = " + b"[" * 5000 + b"]" * 5000 + b"\n", "nested too deeply"),
    "invalid TOML": (b"[mesh\n", "not valid TOML"),
    "a key twice": (b"[load]\nforce = 1.0\nforce = 2.0\n", "not valid TOML"),
}


@pytest.mark.parametrize("content,words", PROBLEM_BYTES.values(), ids=PROBLEM_BYTES.keys())
def test_unreadable_problem_files(tmp_path, capsys, content, words):
    path = tmp_path / "p.toml"
    path.write_bytes(content)
    assert_refused(solve_cli(tmp_path, path), capsys.readouterr().err, "problem", words)


@pytest.mark.parametrize("kind", ["directory", "missing", "too large", "no permission", "device"])
def test_problem_paths_that_are_not_readable_files(tmp_path, capsys, monkeypatch, kind):
    path = tmp_path / "p.toml"
    if kind == "directory":
        path.mkdir()
    elif kind == "too large":  # a sparse 1 GiB file: refused by its size, never read
        with open(path, "wb") as fh:
            fh.truncate(2**30)
    elif kind == "no permission":  # root reads anything, so permission is denied by os.access here
        write_toml(path, small_cylinder())
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == path else real(p, mode, **kw))
    elif kind == "device":
        path = Path("/dev/null")
    words = {"directory": "is a directory", "missing": "not found", "too large": "1 GiB",
             "no permission": "permission denied", "device": "not a regular file"}[kind]
    assert_refused(solve_cli(tmp_path, path), capsys.readouterr().err, "problem", words)


def test_byte_order_mark_is_skipped(tmp_path):
    path = tmp_path / "p.toml"
    path.write_bytes(b"\xef\xbb\xbf[load]\nforce = 1.0\n")
    assert ep.read_toml(path) == {"load": {"force": 1.0}}


# ============================================================================
# 2. hostile values in the problem
# ============================================================================

BIG = 10**400  # TOML integers are parsed exactly; float(BIG) overflows

VALUES = [
    # (dotted key, value, field named, words in the message)
    ("load.force", float("inf"), "load.force", "finite"),
    ("load.force", float("nan"), "load.force", "finite"),
    ("load.force", BIG, "load.force", "finite"),
    ("load.force", -0.0, "load.force", "> 0"),
    ("load.force", "10", "load.force", "finite"),
    ("load.force", True, "load.force", "finite"),
    ("load.force", [1.0], "load.force", "finite"),
    ("load.force", {"a": 1}, "load.force", "finite"),
    ("material.E", float("inf"), "material.E", "finite"),
    ("material.nu", 0.5, "material.nu", "(-1, 0.5)"),
    ("material.nu", "0.3", "material.nu", "finite"),
    ("material.yield_stress", BIG, "material.yield_stress", "characters"),  # cut to one readable line
    ("material.hardening", float("-inf"), "material.hardening", "finite"),
    ("material.hardening", [0.0], "material.hardening", "finite"),
    ("mesh.divisions", [8.0, 4], "mesh.divisions", "integers"),
    ("mesh.divisions", [[8], [4]], "mesh.divisions", "integers"),
    ("mesh.divisions", ["8", "4"], "mesh.divisions", "integers"),
    ("mesh.divisions", [True, 4], "mesh.divisions", "integers"),
    ("mesh.divisions", [-8, 4], "mesh.divisions", "integers"),
    ("mesh.divisions", [8, 4, 2], "mesh.divisions", "integers"),
    ("mesh.size", [float("inf"), 10.0], "mesh.size", "finite"),
    ("mesh.size", [BIG, 10.0], "mesh.size", "finite"),
    ("mesh.size", "20x10", "mesh.size", "finite"),
    ("mesh.size", [1e-300, 1e-300], "mesh.size", "between 1e-50 and 1e+50"),
    ("mesh.size", [1e300, 1e300], "mesh.size", "between 1e-50 and 1e+50"),
    ("mesh.size", [40.0, 1e-5], "mesh.size", "times longer"),  # cells 2e6 x 1e-5: aspect ratio 2e5 x 10
    ("mesh.grading", 1e10, "mesh.grading", "smaller grading"),  # t**1e10 = 0: coincident nodes
    ("mesh.grading", 50.0, "mesh.grading", "smaller grading"),  # (1/4)**50 = 8e-31 of the side
    ("mesh.grading", "1.5", "mesh.grading", "finite"),
    ("mesh.origin", [float("inf"), 0.0], "mesh.origin", "finite"),
    ("mesh.origin", [1e20, 0.0], "mesh.origin", "round-off"),  # spacing 1 beside 1e20: lost
    ("mesh.contact_center", [1e299], "mesh.contact_center", "outside the bottom face"),
    ("mesh.contact_center", [float("nan")], "mesh.contact_center", "finite"),
    ("mesh.contact_radius", 1e300, "mesh.contact_radius", "reaches the side"),
    ("mesh.contact_radius", 50.0, "mesh.contact_radius", "reaches the side"),  # the block is 40 wide
    ("mesh.contact_radius", 1e-300, "mesh.contact_radius", "no bottom facet"),
    ("mesh.pattern", ["crossed"], "mesh.pattern", "diagonal"),
    ("mesh.generator", ["rectangle"], "mesh.generator", "one of"),
    ("obstacle.shape", ["cylinder"], "obstacle.shape", "one of"),
    ("obstacle.center", [float("inf")], "obstacle.center", "finite"),
    ("obstacle.center", ["0"], "obstacle.center", "finite"),
    ("obstacle.radius", float("inf"), "obstacle.radius", "finite"),
    ("solver.method", ["conic"], "solver.method", "unknown method"),
    ("solver.max_iter", 10**17, "solver.max_iter", "must be"),
    ("solver.tol", 1.0, "solver.tol", "must be"),  # relative residuals: 1 accepts anything
    ("solver.tol", float("nan"), "solver.tol", "must be"),
    ("solver.tol", BIG, "solver.tol", "must be"),
]


@pytest.mark.parametrize("key,value,field,words", VALUES,
                         ids=[f"{k}={str(v)[:20]}" for k, v, *_ in (getattr(p, "values", p) for p in VALUES)])
def test_hostile_values_name_their_field(tmp_path, capsys, key, value, field, words):
    data = small_cylinder()
    section, name = key.split(".")
    data.setdefault(section, {})[name] = value
    refused(tmp_path, capsys, data, field, words)


def test_paraboloid_too_sharp_for_the_solvers(tmp_path, capsys):
    # psi = r^2 / (2 R) = 1e300-ish at the zone's edge: refused rather than sent to the solver
    data = small_cylinder()
    data["obstacle"] = {"shape": "paraboloid", "radius": 1e-300}
    refused(tmp_path, capsys, data, "obstacle.radius", "rises to")


def test_negative_zero_hardening_is_zero():
    with pytest.warns(UserWarning, match="perfect plasticity"):
        m = ep.make_material(1.0, 0.3, 1e-3, -0.0)
    assert m.hardening == 0.0 and np.copysign(1.0, m.hardening) == 1.0  # 1/H is +inf, never -inf


def test_nearly_incompressible_warns(tmp_path, capsys):
    data = small_cylinder()
    data["material"]["nu"] = 0.4999
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", data)) == 0
    assert "warning: material.nu = 0.4999 is nearly incompressible" in capsys.readouterr().err


# ============================================================================
# 3. memory: sizes that cannot fit are refused before anything is allocated
# ============================================================================

@pytest.mark.parametrize("generator,divisions", [("rectangle", [10**12, 10**12]), ("rectangle", [10**30, 4]),
                                                 ("rectangle", [10**6, 5 * 10**5]), ("box", [10**4, 10**4, 10**4])])
def test_absurd_divisions_are_refused_at_once(tmp_path, capsys, generator, divisions):
    data = small_cylinder()
    if generator == "box":
        data = ep.read_toml(Path(__file__).parents[1] / "problems" / "sphere_block_3d.toml")
    data["mesh"]["divisions"] = divisions
    start = time.perf_counter()
    line = refused(tmp_path, capsys, data, "mesh.divisions")
    assert time.perf_counter() - start < 5.0  # nothing was allocated (a real attempt takes minutes or dies)
    assert "far beyond any memory" in line or ("needs about" in line and "available" in line)


def test_memory_limit_from_the_environment(tmp_path, capsys, monkeypatch):
    data = small_cylinder()  # 20 x 10 x 2 = 400 triangles: about 360 KB by discretization_bytes
    monkeypatch.setenv(MEMORY_ENV, "100K")
    line = refused(tmp_path, capsys, data, "mesh.divisions", "400 triangles", "more than the 100 KiB available",
                   f"{MEMORY_ENV}=100K")
    need = discretization_bytes(2, *structured_counts([20, 10]))
    assert f"needs about {need / 1024:.3g} KiB" in line
    monkeypatch.setenv(MEMORY_ENV, "lots")
    refused(tmp_path, capsys, data, MEMORY_ENV, "4G")


def test_mesh_file_larger_than_memory_is_refused_before_reading(tmp_path, capsys, monkeypatch):
    with open(tmp_path / "big.msh", "wb") as fh:  # sparse: 100 MiB of size, nothing written
        fh.truncate(100 * 2**20)
    monkeypatch.setenv(MEMORY_ENV, "500M")  # reading a gmsh file needs about 8 x the file: 800 MiB
    data = square_problem("big.msh")
    refused(tmp_path, capsys, data, "mesh.file", "reading", "100 MiB", "needs about 800 MiB")


def test_mesh_file_with_more_elements_than_memory(tmp_path, capsys, monkeypatch):
    path = write_gmsh(tmp_path / "sq.msh", *square(24, 12))
    read_need = mesh_read_bytes(path, path.stat().st_size)
    discretize_need = discretization_bytes(2, 25 * 13, 576, 72)
    assert read_need < discretize_need
    limit = (read_need + discretize_need) // 2  # the file may be read, its 576 triangles not discretized
    monkeypatch.setenv(MEMORY_ENV, str(limit))
    refused(tmp_path, capsys, square_problem("sq.msh"), "mesh.file", "576 triangles", "available")


def test_parse_bytes_and_available_memory(monkeypatch):
    assert parse_bytes("512M") == 512 * 2**20 and parse_bytes("4 GiB") == 4 * 2**30 and parse_bytes("1000") == 1000
    assert parse_bytes("1.5g") == 3 * 2**29
    monkeypatch.setenv(MEMORY_ENV, "2T")
    assert available_memory() == (2 * 2**40, f"{MEMORY_ENV}=2T")
    monkeypatch.delenv(MEMORY_ENV)
    limit, source = available_memory()
    if Path("/proc/meminfo").exists():
        total = int(Path("/proc/meminfo").read_text().split("MemTotal:")[1].split()[0]) * 1024
        assert 0 < limit <= total, source


@pytest.mark.parametrize("dim,divisions", [(2, [60, 30]), (3, [12, 12, 6])])
def test_memory_estimate_matches_a_real_build(dim, divisions):
    """The estimate bounds the traced peak of building the mesh and its operators,
    without overstating it more than 1.3 times (the model is the largest measured
    peak per element; tracemalloc sees every NumPy allocation). If the build's memory
    changes, this fails and discretization_bytes must be recounted."""
    base = ep.read_toml(Path(__file__).parents[1] / "problems" /
                                ("cylinder_2d.toml" if dim == 2 else "sphere_block_3d.toml"))
    base["mesh"]["divisions"] = divisions
    tracemalloc.start()
    try:
        disc = ep.discretize(ep.problem_from_dict(base))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    n_nodes, n_el, n_facets = structured_counts(divisions)
    assert (disc.mesh.n_nodes, disc.n_elements) == (n_nodes, n_el)
    estimate = discretization_bytes(dim, n_nodes, n_el, n_facets)
    assert estimate / 1.3 <= peak <= estimate, (peak, estimate)


# ============================================================================
# 4. mesh files: element types, one conforming body, unreadable files
# ============================================================================

GROUP_NAMES = {1: "bottom", 2: "top", 3: "left", 4: "right"}


def write_gmsh(path: Path, points, cells: list[tuple[str, np.ndarray, int]], names=None) -> Path:
    """A gmsh 2.2 file: ``cells`` are (meshio type, node table, physical tag)."""
    names = GROUP_NAMES if names is None else names
    pts = np.asarray(points, float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    blocks = [(t, np.asarray(c, dtype=np.int64)) for t, c, _ in cells]
    tags = [np.full(len(c), tag) for _, c, tag in cells]
    dims = {"line": 1, "triangle": 2, "quad": 2, "tetra": 3, "hexahedron": 3, "wedge": 3, "pyramid": 3, "vertex": 0}
    field = {name: np.array([tag, dims[next(t for t, _, g in cells if g == tag)]])
             for tag, name in names.items() if any(g == tag for _, _, g in cells)}
    meshio.write(path, meshio.Mesh(pts, blocks, cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                                   field_data=field), file_format="gmsh22", binary=False)
    return path


def grid(nx: int, ny: int, x0: float = 0.0, width: float = 2.0, height: float = 1.0):
    """Nodes of an (nx+1) x (ny+1) grid on [x0, x0 + width] x [0, height], index i + (nx+1) j."""
    x, y = np.meshgrid(np.linspace(x0, x0 + width, nx + 1), np.linspace(0.0, height, ny + 1))
    return np.column_stack([x.ravel(), y.ravel()])


def grid_triangles(nx: int, ny: int, offset: int = 0) -> np.ndarray:
    i, j = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny)))
    a = offset + i + (nx + 1) * j
    return np.concatenate([np.stack([a, a + 1, a + nx + 2], 1), np.stack([a, a + nx + 2, a + nx + 1], 1)])


def grid_sides(nx: int, ny: int, offset: int = 0) -> list[tuple[str, np.ndarray, int]]:
    """The four sides of a grid as tagged line cells (bottom 1, top 2, left 3, right 4)."""
    row = np.arange(nx)
    col = np.arange(ny) * (nx + 1)
    bottom = np.stack([row, row + 1], 1)
    top = bottom + ny * (nx + 1)
    left = np.stack([col, col + nx + 1], 1)
    right = left + nx
    return [("line", s + offset, tag) for s, tag in ((bottom, 1), (top, 2), (left, 3), (right, 4))]


def square(nx: int = 4, ny: int = 2):
    """A conforming triangle grid on [0, 2] x [0, 1] with its sides tagged."""
    return grid(nx, ny), [("triangle", grid_triangles(nx, ny), 100)] + grid_sides(nx, ny)


def square_problem(filename: str) -> dict:
    return {"mesh": {"file": filename},
            "material": {"E": 1000.0, "nu": 0.3, "yield_stress": 10.0, "hardening": 100.0},
            "boundary": {"clamped": ["top"], "contact": ["bottom"], "fix_component": {"x": ["left", "right"]}},
            "obstacle": {"shape": "flat"}, "load": {"force": 1.0}}


def mesh_refused(tmp_path, capsys, points, cells, *words, names=None, problem=None) -> str:
    write_gmsh(tmp_path / "m.msh", points, cells, names)
    return refused(tmp_path, capsys, problem or square_problem("m.msh"), "mesh.file", *words)


def test_a_conforming_square_is_read_and_solved(tmp_path, capsys):
    write_gmsh(tmp_path / "m.msh", *square())
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", square_problem("m.msh"))) == 0
    assert "warning" not in capsys.readouterr().err


def test_quadrilaterals_beside_triangles(tmp_path, capsys):
    """The issue's case: triangles on the left half, quadrilaterals on the right
    half; the quads used to be dropped silently (U off by 86%)."""
    corners = [i + 5 * j for j in range(2) for i in range(4)]  # lower-left node of each square, grid(4, 2)
    tris = np.array([t for a in corners if a % 5 < 2 for t in ([a, a + 1, a + 6], [a, a + 6, a + 5])])
    quads = np.array([[a, a + 1, a + 6, a + 5] for a in corners if a % 5 >= 2])
    cells = [("triangle", tris, 100), ("quad", quads, 100)] + grid_sides(4, 2)
    mesh_refused(tmp_path, capsys, grid(4, 2), cells, "4 quad cells beside its 8 triangle cells", "linear triangles")


def test_only_quadrilaterals(tmp_path, capsys):
    quads = np.array([[a + j * 5, a + 1 + j * 5, a + 6 + j * 5, a + 5 + j * 5] for j in range(2) for a in range(4)])
    mesh_refused(tmp_path, capsys, grid(4, 2), [("quad", quads, 100)] + grid_sides(4, 2), "no triangles", "8 quad")


def test_second_order_triangles(tmp_path, capsys):
    pts, cells = square(2, 1)
    tri = cells[0][1]
    mids = np.stack([(pts[tri[:, a]] + pts[tri[:, (a + 1) % 3]]) / 2 for a in range(3)], axis=1)  # mid-edge nodes
    t6 = np.concatenate([tri, len(pts) + np.arange(3 * len(tri)).reshape(-1, 3)], axis=1)
    pts = np.concatenate([pts, mids.reshape(-1, 2)])
    path = tmp_path / "m.msh"
    meshio.write(path, meshio.Mesh(np.column_stack([pts, np.zeros(len(pts))]),
                                   [("triangle6", t6), ("triangle", tri[:1])]), file_format="gmsh22", binary=False)
    refused(tmp_path, capsys, square_problem("m.msh"), "mesh.file", "4 triangle6 cells beside its 1 triangle cells")


def test_line_cells_inside_the_body(tmp_path, capsys):
    pts, cells = square(4, 2)
    middle = np.array([[5, 6], [6, 7]])  # along y = 0.5, between two rows of triangles
    mesh_refused(tmp_path, capsys, pts, cells + [("line", middle, 5)], "group 'inner'", "inside the body",
                 names={**GROUP_NAMES, 5: "inner"})


def test_line_cells_that_are_no_element_edge(tmp_path, capsys):
    pts, cells = square(4, 2)
    mesh_refused(tmp_path, capsys, pts, cells + [("line", np.array([[0, 14]]), 5)], "group 'diagonal'",
                 "not faces of any element", names={**GROUP_NAMES, 5: "diagonal"})


def test_two_disconnected_parts(tmp_path, capsys):
    pts, cells = square(4, 2)
    far = pts + [5.0, 0.0]  # a second square beside the first, not touching it
    cells = cells + [("triangle", grid_triangles(4, 2, offset=len(pts)), 100)]
    mesh_refused(tmp_path, capsys, np.concatenate([pts, far]), cells, "2 disconnected parts", "16, 16 elements")


def test_parts_touching_at_a_corner(tmp_path, capsys):
    pts, cells = square(2, 1)
    corner = pts + [2.0, 1.0]  # its node (0, 0) falls on the first square's corner (2, 1) and is merged
    cells = cells + [("triangle", grid_triangles(2, 1, offset=len(pts)), 100)]
    mesh_refused(tmp_path, capsys, np.concatenate([pts, corner]), cells, "touch only at vertices")


def test_repeated_element(tmp_path, capsys):
    pts, cells = square(4, 2)
    tri = cells[0][1]
    mesh_refused(tmp_path, capsys, pts, [("triangle", np.concatenate([tri, tri[3:4, ::-1]]), 100)] + cells[1:],
                 "1 element(s) repeat")


def test_facet_shared_by_three_triangles(tmp_path, capsys):
    pts, cells = square(4, 2)
    tri = cells[0][1]
    # triangle (0, 6, 2) overlaps the others and puts the interior edge 0-6 on three triangles
    mesh_refused(tmp_path, capsys, pts, [("triangle", np.concatenate([tri, [[0, 6, 2]]]), 100)] + cells[1:],
                 "3 or more elements")


def test_hanging_node_at_the_boundary(tmp_path, capsys):
    """[0,1]^2 in two triangles beside [1,2]x[0,1] in four: node (1, 0.5) hangs on
    the left square's edge."""
    pts = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [2, 0], [2, 0.5], [2, 1], [1, 0.5]], float)
    tris = np.array([[0, 1, 3], [0, 3, 2], [1, 4, 5], [1, 5, 7], [7, 5, 6], [7, 6, 3]])
    lines = [("line", np.array([[0, 1], [1, 4]]), 1), ("line", np.array([[2, 3], [3, 6]]), 2),
             ("line", np.array([[0, 2]]), 3), ("line", np.array([[4, 5], [5, 6]]), 4)]
    mesh_refused(tmp_path, capsys, pts, [("triangle", tris, 100)] + lines, "non-conforming interface")


def test_hanging_node_inside(tmp_path, capsys):
    """A 3 x 3 grid of unit squares in which the edge (1,1)-(2,1) of the lower middle
    square meets a node (1.5, 1) of the square above: the boundary ridges all lie on
    two facets, but the two sides of the edge fold onto each other."""
    pts = grid(3, 3, width=3.0, height=3.0)
    tris = grid_triangles(3, 3)
    a, b, c, d = 5, 6, 9, 10  # (1,1), (2,1), (1,2), (2,2)
    upper = np.array([[a, b, d], [a, d, c]])
    keep = ~np.array([sorted(t) in (sorted(u) for u in upper) for t in tris.tolist()])
    m = len(pts)
    pts = np.concatenate([pts, [[1.5, 1.0]]])
    tris = np.concatenate([tris[keep], [[a, m, c], [m, d, c], [m, b, d]]])
    line = mesh_refused(tmp_path, capsys, pts, [("triangle", tris, 100)] + grid_sides(3, 3), "folds back")
    assert "[5]" in line or "[6]" in line  # at the ends (1,1) or (2,1) of the edge


def test_coincident_nodes_are_merged(tmp_path, capsys):
    """Two halves meshed separately, with their own copies of the nodes on x = 1:
    merged (with a warning) into the conforming mesh, which is then solved."""
    left, right = grid(2, 2, width=1.0), grid(2, 2, x0=1.0, width=1.0)
    n = len(left)
    cells = [("triangle", grid_triangles(2, 2), 100), ("triangle", grid_triangles(2, 2, offset=n), 100)]
    sides = grid_sides(2, 2)
    cells += [sides[0], sides[1], sides[2], ("line", grid_sides(2, 2, offset=n)[0][1], 1),
              ("line", grid_sides(2, 2, offset=n)[1][1], 2), ("line", grid_sides(2, 2, offset=n)[3][1], 4)]
    write_gmsh(tmp_path / "m.msh", np.concatenate([left, right]), cells)
    with pytest.warns(UserWarning, match="merged 3 coincident node"):
        mesh = ep.read_mesh(tmp_path / "m.msh")
    assert mesh.n_nodes == 15 and mesh.n_elements == 16  # the 5 x 3 grid of the whole
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", square_problem("m.msh"))) == 0
    assert "warning: mesh.file: merged 3 coincident node(s)" in capsys.readouterr().err


def test_triangle_soup_is_merged_into_one_body(tmp_path):
    """Every triangle with its own three nodes (some exporters write this)."""
    pts, cells = square(4, 2)
    tri = cells[0][1]
    soup = pts[tri].reshape(-1, 2)  # the side lines stay on the grid's nodes
    write_gmsh(tmp_path / "m.msh", np.concatenate([pts, soup]),
               [("triangle", np.arange(len(soup)).reshape(-1, 3) + len(pts), 100)] + cells[1:])
    with pytest.warns(UserWarning, match="merged"):
        mesh = ep.read_mesh(tmp_path / "m.msh")
    assert (mesh.n_nodes, mesh.n_elements) == (15, 16)


def test_non_finite_coordinates(tmp_path, capsys):
    pts, cells = square()
    pts[7] = [np.nan, 0.5]
    mesh_refused(tmp_path, capsys, pts, cells, "not finite")


def test_triangles_out_of_plane(tmp_path, capsys):
    """A surface mesh in 3D (here the square tilted) is not a plane-strain body."""
    pts, cells = square()
    write_gmsh(tmp_path / "m.msh", np.column_stack([pts, pts[:, 0]]), cells)
    refused(tmp_path, capsys, square_problem("m.msh"), "mesh.file", "plane z = 0")


GARBAGE = {
    "text.msh": b"hello, this is not a mesh\n",
    "binary.msh": bytes(range(256)) * 20,
    "text.vtu": b"hello\n",
    "binary.vtu": bytes(range(256)) * 20,
    "text.vtk": b"hello\n",
    "text.xdmf": b"hello\n",
    "binary.xdmf": bytes(range(256)),
    "text.mesh": b"hello\n",
    "text.off": b"hello\n",
    "binary.stl": bytes(range(256)) * 3,
    "text.su2": b"hello\n",
    "text.obj": b"hello\n",
    "mesh.foo": b"hello\n",
    "empty.msh": b"",
    "truncated.msh": b"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n1 0 0 0\n",
}


@pytest.mark.parametrize("name", GARBAGE)
def test_files_that_are_not_meshes(tmp_path, capsys, name):
    """meshio ends some failures with sys.exit(1) and prints to stdout/stderr: all of
    it becomes one line naming mesh.file."""
    (tmp_path / name).write_bytes(GARBAGE[name])
    code = solve_cli(tmp_path, write_toml(tmp_path / "p.toml", square_problem(name)))
    out, err = capsys.readouterr()
    assert_refused(code, err, "mesh.file")
    assert out == ""


@pytest.mark.parametrize("kind", ["directory", "no permission", "NUL in path", "empty name"])
def test_mesh_paths_that_are_not_readable_files(tmp_path, capsys, monkeypatch, kind):
    name = {"directory": "d.msh", "no permission": "m.msh", "NUL in path": "a\x00b.msh", "empty name": ""}[kind]
    if kind == "directory":
        (tmp_path / name).mkdir()
    if kind == "no permission":
        mesh = write_gmsh(tmp_path / name, *square())
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == mesh else real(p, mode, **kw))
    words = {"directory": "is a directory", "no permission": "permission denied", "NUL in path": "invalid path",
             "empty name": "is a directory"}[kind]
    refused(tmp_path, capsys, square_problem(name), "mesh.file", words)


def test_own_output_read_as_a_mesh(tmp_path, capsys):
    """solution.vtu has triangles but no facet groups: the boundary groups are unknown."""
    write_gmsh(tmp_path / "m.msh", *square())
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", square_problem("m.msh"))) == 0
    capsys.readouterr()
    data = square_problem(str(tmp_path / "out" / "solution.vtu"))
    refused(tmp_path, capsys, data, "boundary.clamped", "unknown group")


def box_cells(nx=2, ny=1, nz=1, x0=0.0):
    mesh = ep.structured_mesh([float(nx), float(ny), float(nz)], [nx, ny, nz], 0.3, origin=[x0, 0.0, 0.0],
                              contact_center=[x0 + nx / 2, ny / 2])
    return mesh


def write_box(path: Path, meshes: list[ep.Mesh], extra=()) -> Path:
    pts, cells, offset = [], [], 0
    names = {}
    for mesh in meshes:
        pts.append(mesh.points)
        cells.append(("tetra", mesh.cells + offset, 100))
        for k, (name, facets) in enumerate(mesh.groups.items()):
            names[k + 1] = name
            cells.append(("triangle", facets + offset, k + 1))
        offset += mesh.n_nodes
    return write_gmsh(path, np.concatenate(pts), cells + list(extra), names)


BOX_PROBLEM = {"mesh": {"file": "b.msh"}, "material": {"E": 1000.0, "nu": 0.3, "yield_stress": 10.0, "hardening": 100.0},
               "boundary": {"clamped": ["top", "xmin", "xmax", "ymin", "ymax"], "contact": ["contact"]},
               "obstacle": {"shape": "flat"}, "load": {"force": 1.0}}


def test_box_file_round_trip(tmp_path):
    box = box_cells(2, 2, 1)
    mesh = ep.read_mesh(write_box(tmp_path / "b.msh", [box]))
    assert np.array_equal(mesh.cells, box.cells) and np.array_equal(mesh.points, box.points)
    for name, facets in box.groups.items():  # empty groups have no cells in the file
        assert np.array_equal(mesh.groups.get(name, facets[:0]), facets)


@pytest.mark.parametrize("kind,cell,nodes", [("hexahedra", "hexahedron", 8), ("prisms", "wedge", 6),
                                             ("pyramids", "pyramid", 5)])
def test_3d_cells_beside_tetrahedra(tmp_path, capsys, kind, cell, nodes):
    box = box_cells()
    extra = [(cell, np.arange(nodes)[None, :], 100)]
    write_box(tmp_path / "b.msh", [box], extra)
    refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", f"1 {cell} cells beside", "linear tetrahedra")


def test_3d_triangles_inside_the_body(tmp_path, capsys):
    box = box_cells()
    facets = np.sort(np.concatenate([np.delete(box.cells, i, 1) for i in range(4)]), axis=1)
    uniq, counts = np.unique(facets, axis=0, return_counts=True)
    inner = uniq[counts == 2][:3]
    write_box(tmp_path / "b.msh", [box], [("triangle", inner, 50)])
    refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", "3 facet(s) of group '50'", "inside the body")


def test_3d_lines_that_are_no_edges(tmp_path, capsys):
    box = box_cells()
    far = np.array([[0, box.n_nodes - 1]])  # opposite corners of the box
    write_box(tmp_path / "b.msh", [box], [("line", far, 60)])
    refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", "not edges of any tetrahedron")


def test_3d_two_boxes_apart(tmp_path, capsys):
    write_box(tmp_path / "b.msh", [box_cells(), box_cells(x0=5.0)])
    refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", "2 disconnected parts")


def test_3d_faces_split_differently_on_an_interface(tmp_path, capsys):
    """A 2 x 2 x 1 box of unit cubes in which one cube's six tetrahedra are mirrored
    in y: its face x = 1 is now split along the other diagonal than its neighbour's,
    while its other faces still match (the mesh stays connected through them)."""
    whole = ep.structured_mesh([2.0, 2.0, 1.0], [2, 2, 1], 0.3, origin=[0.0, 0.0, 0.0], contact_center=[1.0, 1.0])
    centroid = whole.points[whole.cells].mean(axis=1)
    cube = (centroid[:, 0] > 1) & (centroid[:, 1] < 1)
    node_at = {tuple(p): i for i, p in enumerate(whole.points.tolist())}
    mirror = whole.points * [1, -1, 1] + [0, 1, 0]  # y -> 1 - y, within the cube
    image = np.array([node_at.get(tuple(p), -1) for p in mirror.tolist()])
    mirrored = image[whole.cells[cube]][:, [1, 0, 2, 3]]  # mirroring reverses orientation
    assert np.all(mirrored >= 0)
    mesh = ep.Mesh(whole.points, np.concatenate([whole.cells[~cube], mirrored]), whole.groups)
    write_box(tmp_path / "b.msh", [mesh])
    line = refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file")
    assert "not a closed surface" in line or "folds back" in line


@pytest.mark.parametrize("split_differently", [True, False])
def test_3d_one_face_split_differently_inside(tmp_path, capsys, split_differently):
    """In a 2 x 3 x 3 box of unit cubes, the middle cube of the right half is remeshed
    as a cone from its centre over its faces, with its face on x = 1 split along the
    other diagonal. Everything else matches, so every boundary edge still lies on two
    boundary facets: the mismatch shows as the two sides of that square folding onto
    each other. The same cone with the square split as before is a conforming mesh.
    """
    whole = ep.structured_mesh([2.0, 3.0, 3.0], [2, 3, 3], 0.3, origin=[0.0, 0.0, 0.0], contact_center=[1.0, 1.0])
    X = whole.points
    centroid = X[whole.cells].mean(axis=1)
    cube = np.all((centroid > [1, 1, 1]) & (centroid < [2, 2, 2]), axis=1)
    faces = np.sort(np.concatenate([np.delete(whole.cells[cube], i, 1) for i in range(4)]), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    skin = uniq[counts == 1]  # the cube's 12 face triangles
    on_q = np.all(X[skin][:, :, 0] == 1.0, axis=1)
    q = skin[on_q]
    shared = np.intersect1d(q[0], q[1])  # the diagonal the square is split along now
    other = np.setdiff1d(np.union1d(q[0], q[1]), shared)
    if split_differently:
        skin = np.concatenate([skin[~on_q], [[other[0], other[1], shared[0]], [other[0], other[1], shared[1]]]])
    centre = len(X)
    cone = np.column_stack([np.full(len(skin), centre), skin])
    points = np.concatenate([X, [[1.5, 1.5, 1.5]]])
    J = points[cone[:, 1:]] - points[cone[:, :1]]
    flip = np.linalg.det(J) < 0
    cone[flip, 1:3] = cone[flip, 2:0:-1]
    mesh = ep.Mesh(points, np.concatenate([whole.cells[~cube], cone]), whole.groups)
    write_box(tmp_path / "b.msh", [mesh])
    if split_differently:
        refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", "folds back onto itself at 4 boundary edge(s)")
    else:
        assert ep.read_mesh(tmp_path / "b.msh").n_elements == whole.n_elements - 6 + 12


def test_3d_hanging_nodes(tmp_path, capsys):
    """A unit cube beside a cube cut into 2 x 2 x 2: the middle of their shared face
    is a node on one side only."""
    coarse = box_cells(1, 1, 1)
    fine = ep.structured_mesh([1.0, 1.0, 1.0], [2, 2, 2], 0.3, origin=[1.0, 0.0, 0.0], contact_center=[1.5, 0.5])
    write_box(tmp_path / "b.msh", [coarse, fine])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        refused(tmp_path, capsys, BOX_PROBLEM, "mesh.file", "non-conforming interface")


def test_hanging_node_check_alone():
    """A node on a boundary facet that is not its vertex is found by the k-d tree test
    even where ridge counts and folds cannot see it (called on its own here)."""
    from elastoplast.mesh.checks import check_hanging_nodes

    pts = np.array([[0, 0], [2, 0], [1, 0], [1, 1]], float)
    facets = np.array([[0, 1], [0, 2], [2, 3]])  # node 2 lies on facet 0-1
    with pytest.raises(InputError, match="hang"):
        check_hanging_nodes(pts, facets, "mesh.file")
    check_hanging_nodes(pts + [[0, 0], [0, 0], [0, 0.1], [0, 0]], facets, "mesh.file")  # off the line: none


@contextlib.contextmanager
def gmsh_model(name: str):
    """The gmsh API, initialised with one empty model (skips without gmsh)."""
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        yield gmsh
    finally:
        gmsh.finalize()


def test_gmsh_recombined_quads(tmp_path, capsys):
    """A real gmsh mesh with quadrilaterals recombined beside triangles."""
    with gmsh_model("mixed") as gmsh:
        left = gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
        right = gmsh.model.occ.addRectangle(1, 0, 0, 1, 1)
        gmsh.model.occ.fragment([(2, left)], [(2, right)])
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        gmsh.model.mesh.setRecombine(2, right)
        gmsh.model.addPhysicalGroup(2, [left, right], name="body")
        bottom = [t for _, t in gmsh.model.getEntitiesInBoundingBox(-1, -1e-6, -1, 3, 1e-6, 1, dim=1)]
        gmsh.model.addPhysicalGroup(1, bottom, name="bottom")
        gmsh.model.mesh.generate(2)
        gmsh.write(str(tmp_path / "m.msh"))
    data = square_problem("m.msh")
    refused(tmp_path, capsys, data, "mesh.file", "quad", "beside")


def gmsh_two_rectangles(path: Path, *, fragment: bool, right_size: float | None) -> Path:
    """Two unit squares side by side meshed by gmsh, sharing their interface (fragment)
    or each meshed on its own (gmsh then writes the interface nodes twice)."""
    with gmsh_model("two") as gmsh:
        left, right = gmsh.model.occ.addRectangle(0, 0, 0, 1, 1), gmsh.model.occ.addRectangle(1, 0, 0, 1, 1)
        if fragment:
            gmsh.model.occ.fragment([(2, left)], [(2, right)])
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        if right_size is not None:  # on the right square's own copy of the interface points too
            gmsh.model.mesh.setSize(gmsh.model.getBoundary([(2, right)], recursive=True), right_size)
        gmsh.model.addPhysicalGroup(2, [t for _, t in gmsh.model.getEntities(2)], name="body")
        for name, box in (("bottom", (-1, -1e-6, -1, 3, 1e-6, 1)), ("top", (-1, 1 - 1e-6, -1, 3, 1 + 1e-6, 1)),
                          ("left", (-1e-6, -1, -1, 1e-6, 2, 1)), ("right", (2 - 1e-6, -1, -1, 2 + 1e-6, 2, 1))):
            curves = [t for _, t in gmsh.model.getEntitiesInBoundingBox(*box, dim=1)]
            gmsh.model.addPhysicalGroup(1, curves, name=name)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    return path


@pytest.mark.parametrize("fragment,right_size,outcome", [(True, None, "read"), (False, None, "merged"),
                                                         (False, 0.1, "refused")])
def test_gmsh_volumes_meshed_apart(tmp_path, capsys, fragment, right_size, outcome):
    """gmsh meshes of two touching squares: fragmented (one conforming mesh), not
    fragmented with the same sizes (the interface meshed twice alike: its duplicate
    nodes merged, then conforming), and not fragmented with a finer right square (a
    non-conforming interface)."""
    gmsh_two_rectangles(tmp_path / "m.msh", fragment=fragment, right_size=right_size)
    code = solve_cli(tmp_path, write_toml(tmp_path / "p.toml", square_problem("m.msh")))
    err = capsys.readouterr().err
    if outcome == "refused":
        assert_refused(code, err, "mesh.file", "non-conforming interface")
    else:
        assert code == 0, err
        assert ("merged" in err) == (outcome == "merged")


def test_gmsh_untagged_facets_are_ignored(tmp_path):
    """With Mesh.SaveAll gmsh writes every line with physical tag 0, an embedded
    line inside the square too: in no group, and faces of elements, so accepted."""
    with gmsh_model("embedded") as gmsh:
        square_tag = gmsh.model.occ.addRectangle(0, 0, 0, 2, 1)
        a, b = gmsh.model.occ.addPoint(0.5, 0.5, 0), gmsh.model.occ.addPoint(1.5, 0.5, 0)
        line = gmsh.model.occ.addLine(a, b)
        gmsh.model.occ.synchronize()
        gmsh.model.mesh.embed(1, [line], 2, square_tag)
        gmsh.option.setNumber("Mesh.SaveAll", 1)
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(tmp_path / "e.msh"))
    raw = meshio.read(tmp_path / "e.msh")
    lines = np.concatenate([b.data for b in raw.cells if b.type == "line"])
    assert np.any(np.all(np.isclose(raw.points[lines][:, :, 1], 0.5), axis=1))  # the embedded line is there
    mesh = ep.read_mesh(tmp_path / "e.msh")
    assert dict(mesh.groups) == {} and mesh.n_elements > 0


def test_one_division_spans_the_side():
    """graded_nodes with one division and the contact centre inside used to return
    [centre, end], a mesh of half the block."""
    mesh = ep.structured_mesh([4.0, 2.0, 1.0], [1, 1, 1], 0.5)
    assert np.allclose(mesh.points.min(axis=0), [-2, -1, 0]) and np.allclose(mesh.points.max(axis=0), [2, 1, 1])
    X = mesh.points[mesh.cells]
    volume = np.abs(np.linalg.det(X[:, 1:] - X[:, :1])).sum() / 6
    assert volume == pytest.approx(8.0)


# ============================================================================
# 5. obstacle expressions: bounded cost, psi >= 0 and finite
# ============================================================================

EXPRESSIONS = [
    ("9**9**9**9", "not finite"),              # Python integers would compute for hours
    ("x**2 + 10**10**8", "not finite"),        # and here take minutes and gigabytes
    ("1" + "0" * 1990 + "*x", "not finite"),  # an integer literal beyond the float range
    ("__import__('os').system('true')", "calls must be"),
    ("x.__class__", "Attribute is not allowed"),
    ("(lambda: 1)()", "calls must be"),
    ("[x for x in x]", "ListComp is not allowed"),
    ("+".join(["x"] * 1001), "at most 2000"),
    ("-" * 1000 + "x", "syntax nodes"),
    ("(" * 300 + "x" + ")" * 300, "cannot parse"),
    ("x\x00", "cannot parse"),
    ("", "cannot parse"),
    ("'abc'", "only real numbers"),
    ("True", "only real numbers"),
    ("1j*x", "only real numbers"),
    ("y**2", "unknown name 'y'"),
    ("sqrt(x, out=x)", "calls must be"),
    ("sqrt(x, x)", "calls must be"),          # a second argument would be numpy's out=
    ("where(x > 0)", "calls must be"),
    ("maximum(x)", "calls must be"),
    ("pi(1)", "calls must be"),
    ("x @ x", "MatMult is not allowed"),
    ("x << 2", "LShift is not allowed"),
    ("x if x > 0 else -x", "where(condition, a, b)"),
    ("0.01*x**2 - 1", "negative"),
    ("sqrt(x)", "not finite"),
    ("1/x", "not finite"),
    ("log(abs(x))", "not finite"),
    ("exp(1000*x)", "not finite"),
    ("exp(50*x)", "rises to"),                # finite, but 1e54 over a zone of width 5
]


@pytest.mark.parametrize("expr,words", EXPRESSIONS, ids=[e[:30] for e, _ in EXPRESSIONS])
def test_expression_obstacles(tmp_path, capsys, expr, words):
    data = small_cylinder()
    data["obstacle"] = {"shape": "expression", "expression": expr}
    start = time.perf_counter()
    refused(tmp_path, capsys, data, "obstacle.expression", words)
    assert time.perf_counter() - start < 10.0  # the whole command, mesh included


def test_obstacle_centre_outside_the_zone_warns(tmp_path, capsys):
    data = small_cylinder()
    data["obstacle"] = {"shape": "paraboloid", "radius": 40.0, "center": [100.0]}
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", data)) == 0
    assert "warning: obstacle.center: the obstacle does not touch" in capsys.readouterr().err


def test_expression_that_leaves_a_gap_warns(tmp_path, capsys):
    """psi = 1 + x^2/100 never touches: legal (U is shifted by the gap), said in a warning."""
    data = small_cylinder()
    data["obstacle"] = {"shape": "expression", "expression": "1 + 0.01*x**2"}
    assert solve_cli(tmp_path, write_toml(tmp_path / "p.toml", data)) == 0
    assert "warning: obstacle.expression: the obstacle does not touch" in capsys.readouterr().err


def test_expressions_evaluate_in_floats():
    """Integer constants become float64: 2**-1 is 0.5 (not an int power error) and
    huge powers are inf at once."""
    from elastoplast.problem.expressions import compile_expression

    code, consts = compile_expression("2**-1 + x*0 + 7//2", 2, "obstacle.expression")
    x = np.array([0.0, 1.0])
    assert np.array_equal(eval(code, {"__builtins__": {}}, {**consts, "x": x}), [3.5, 3.5])
    assert all(type(v) is np.float64 for v in consts.values())
    start = time.perf_counter()
    code, consts = compile_expression("9**9**9**9", 2, "obstacle.expression")
    with np.errstate(all="ignore"):
        assert eval(code, {"__builtins__": {}}, consts) == np.inf
    assert time.perf_counter() - start < 1.0


# ============================================================================
# 6. perfect plasticity on meshes that lock
# ============================================================================

def rectangle(pattern: str, hardening: float = 0.0, divisions=(8, 4)) -> ep.Problem:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ep.problem_from_dict({
            "mesh": {"generator": "rectangle", "size": [4.0, 2.0], "divisions": list(divisions), "grading": 1.3,
                     "contact_radius": 0.5, "pattern": pattern},
            "material": {"E": 200e3, "nu": 0.3, "yield_stress": 250.0, "hardening": hardening},
            "obstacle": {"shape": "flat"}, "load": {"force": 1.0}})


def test_crossed_meshes_pass():
    check_perfect_plasticity(rectangle("crossed"))
    problem = rectangle("crossed")
    centres = crossed_centres(problem.mesh.points, problem.mesh.cells)
    assert centres.sum() == 8 * 4  # one per grid square: the node added in its middle
    assert np.all(np.any(centres[problem.mesh.cells], axis=1))


def test_diagonal_meshes_are_refused():
    with pytest.raises(InputError) as exc:
        check_perfect_plasticity(rectangle("diagonal"))
    assert exc.value.field == "material.hardening"
    assert "64 of 64 triangles" in exc.value.message and "crossed" in exc.value.message
    assert "hardening > 0" in exc.value.message and "elastoplast limit" in exc.value.message
    check_perfect_plasticity(rectangle("diagonal", hardening=1.0))  # H > 0: nothing to refuse


def test_tetrahedra_are_refused():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = ep.read_toml(Path(__file__).parents[1] / "problems" / "sphere_quarter_3d.toml")
        data["mesh"]["divisions"] = [3, 3, 2]
        data["material"]["hardening"] = 0.0
        problem = ep.problem_from_dict(data)
    with pytest.raises(InputError, match="P1 tetrahedra lock") as exc:
        check_perfect_plasticity(problem)
    assert exc.value.field == "material.hardening"


def test_crossed_mesh_from_a_file_passes(tmp_path):
    mesh = rectangle("crossed").mesh
    names = {k + 1: n for k, n in enumerate(mesh.groups)}
    cells = [("triangle", mesh.cells[::-1], 100)] + [("line", mesh.groups[n], k) for k, n in names.items()]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = ep.read_mesh(write_gmsh(tmp_path / "c.msh", mesh.points, cells, names))
    check_perfect_plasticity(ep.Problem(read, ep.Material(200e3, 0.3, 250.0, 0.0), None, None, 1.0))
    # moving one centre off its diagonals' crossing breaks the relation: its four triangles lock
    centre = np.flatnonzero(crossed_centres(read.points, read.cells))[5]
    points = read.points.copy()
    points[centre] += [1e-3, 0.0]
    moved = ep.Mesh(points, read.cells, read.groups)
    with pytest.raises(InputError, match="4 of 128 triangles"):
        check_perfect_plasticity(ep.Problem(moved, ep.Material(200e3, 0.3, 250.0, 0.0), None, None, 1.0))


def test_boundary_nodes_are_never_centres():
    """A crossed square cut in half along a diagonal: its centre is on the boundary,
    with two triangles, and is no centre."""
    pts = np.array([[0, 0], [1, 0], [1, 1], [0.5, 0.5]], float)
    cells = np.array([[0, 1, 3], [1, 2, 3]])
    assert not crossed_centres(pts, cells).any()


def test_perfect_plasticity_warning_points_at_the_check():
    with pytest.warns(UserWarning, match="crossed") as record:
        ep.make_material(1.0, 0.3, 1e-3, 0.0)
    assert "refused by the solvers" in str(record[0].message)


def test_conforming_check_accepts_generated_meshes():
    """Every generated mesh is one conforming body (2D both patterns, 3D, graded)."""
    for problem in (rectangle("crossed"), rectangle("diagonal")):
        check_conforming(problem.mesh.points, problem.mesh.cells, "mesh")
    box = ep.structured_mesh([3.0, 2.0, 1.0], [5, 4, 3], 0.5, grading=1.5)
    check_conforming(box.points, box.cells, "mesh")
