"""The command line, called through ``main(argv)``: outputs and bad input.

Every bad input of the issue must end in exit code 2 and one message naming
the field, never a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import pytest

from elastoplast.cli.main import main
from elastoplast.problem.definition import read_toml

from conftest import PROBLEMS

SUMMARY_KEYS = {"U", "force", "method", "status", "iterations", "time_s", "kkt", "duality_gap",
                "max_contact_pressure", "contact_radius", "plastic_volume_fraction", "n_elements", "n_nodes"}


def small_cylinder() -> dict:
    data = read_toml(PROBLEMS / "cylinder_2d.toml")
    data["mesh"]["divisions"] = [20, 10]
    return data


def write_toml(path: Path, data: dict) -> Path:
    """Minimal TOML writer for the nested tables used here."""
    def value(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, bool):
            return "true" if v else "false"
        return repr(v)

    lines = []

    def table(prefix, d):
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        if prefix:
            lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {value(v)}" for k, v in scalars.items())
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{prefix}.{k}" if prefix else k, v)

    table("", data)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("method", ["conic", "conic-displacement"])
def test_solve_writes_vtu_and_summary(tmp_path, method, capsys):
    problem = write_toml(tmp_path / "p.toml", small_cylinder())
    out = tmp_path / "out"
    assert main(["solve", str(problem), "--method", method, "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert summary["method"] == method and summary["status"] == "converged"
    assert summary["kkt"]["constitutive"] < 1e-6
    vtu = meshio.read(out / "solution.vtu")
    assert {"displacement", "contact_pressure"} <= set(vtu.point_data)
    assert {"stress", "von_mises", "xi", "plastic"} <= set(vtu.cell_data)
    assert vtu.cells[0].data.shape[0] == summary["n_elements"]
    assert np.isclose(vtu.point_data["displacement"][:, 1].max(), summary["U"], rtol=1e-9)  # contact nodes move with B


def test_default_problem_runs(tmp_path, monkeypatch):
    """With no problem file the built-in default is solved (a smaller copy here)."""
    import elastoplast.cli.commands as cli

    data = read_toml(cli.default_problem_path())
    data["mesh"]["divisions"] = [6, 6, 3]
    small = write_toml(tmp_path / "default.toml", data)
    monkeypatch.setattr(cli, "default_problem_path", lambda: small)
    assert main(["solve", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["status"] == "converged"


def _mutate(data: dict, dotted: str, value):
    *path, key = dotted.split(".")
    d = data
    for p in path:
        d = d.setdefault(p, {})
    if value is _DELETE:
        del d[key]
    else:
        d[key] = value
    return data


_DELETE = object()

BAD = [
    # (field named in the message, mutation)
    ("mesh.colour", ("mesh.colour", "red")),
    ("material.nu", ("material.nu", 0.5)),
    ("material.nu", ("material.nu", -1.0)),
    ("material.E", ("material.E", 0.0)),
    ("material.yield_stress", ("material.yield_stress", -5.0)),
    ("material.hardening", ("material.hardening", -1.0)),
    ("load.force", ("load.force", 0.0)),
    ("load.force", ("load.force", "a lot")),
    ("obstacle.radius", ("obstacle.radius", 3.0)),  # Γ0's nodes reach 3.2 from the centre on this mesh
    ("obstacle.shape", ("obstacle.shape", "pyramid")),
    ("obstacle.center", ("obstacle.center", [0.0, 1.0])),
    ("obstacle.expression", ("obstacle.shape", "expression")),
    ("boundary.clamped", ("boundary.clamped", ["xmin", "no_such_group"])),
    ("boundary.contact", ("boundary.contact", [])),
    ("mesh.file", ("mesh.file", "does_not_exist.msh")),
    ("mesh.divisions", ("mesh.divisions", [0, 3])),
    ("problem.extra", ("extra", {"a": 1})),
    ("solver.tolerance", ("solver.tolerance", 1e-8)),
    ("solver.method", ("solver.method", "magic")),
]


@pytest.mark.parametrize("field,mutation", BAD, ids=[f"{m[0]}={m[1]!r}"[:40] for _, m in BAD])
def test_bad_input_exits_2_naming_the_field(tmp_path, capsys, field, mutation):
    data = _mutate(small_cylinder(), *mutation)
    if field == "mesh.file":
        data["mesh"] = {"file": "does_not_exist.msh"}
    code = main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert field in err and "Traceback" not in err
    assert len([line for line in err.splitlines() if line.startswith("error:")]) == 1


def test_rigid_motion_free_is_refused(tmp_path, capsys):
    data = small_cylinder()
    data["boundary"] = {"clamped": ["top"], "contact": ["contact"]}
    assert main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "p"), "--quiet"]) == 0  # top clamped: no motion free, solved
    data["boundary"] = {"clamped": [], "contact": ["contact"], "fix_component": {"y": ["top"]}}
    code = main(["solve", str(write_toml(tmp_path / "q.toml", data)), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "boundary" in err and "rigid motion" in err and "translation x" in err


def test_vertically_fixed_contact_node_is_refused(tmp_path, capsys):
    data = small_cylinder()
    data["boundary"] = {"clamped": ["xmin", "xmax", "top"], "contact": ["bottom"]}  # bottom corners are clamped
    code = main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "boundary.contact" in err and "vertical" in err


def test_unknown_method_is_refused(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", small_cylinder())
    assert main(["solve", str(problem), "--method", "magic"]) == 2
    assert "magic" in capsys.readouterr().err


def _write_msh(path: Path, points, triangles, lines_by_group):
    """A gmsh file with named physical line groups (and one unused node)."""
    names = list(lines_by_group)
    cells = [("triangle", np.asarray(triangles))] + [("line", np.asarray(v)) for v in lines_by_group.values()]
    phys = [np.full(len(triangles), 100)] + [np.full(len(v), i + 1) for i, v in enumerate(lines_by_group.values())]
    field_data = {n: np.array([i + 1, 1]) for i, n in enumerate(names)}
    field_data["body"] = np.array([100, 2])
    mesh = meshio.Mesh(np.asarray(points, float), cells, cell_data={"gmsh:physical": phys, "gmsh:geometrical": phys},
                       field_data=field_data)
    meshio.write(path, mesh, file_format="gmsh22", binary=False)


def _unit_square(path: Path, *, flip: int | None = None, collapse: bool = False):
    # 3x3 nodes on [0,2]x[0,1] plus an unused node 9 (gmsh keeps such nodes)
    pts = [[x, y, 0.0] for y in (0.0, 0.5, 1.0) for x in (0.0, 1.0, 2.0)] + [[5.0, 5.0, 0.0]]
    if collapse:
        pts[4] = [0.5, 0.0, 0.0]  # onto the segment 0-1: triangle (0, 1, 4) becomes flat
    tris = []
    for j in range(2):
        for i in range(2):
            a = 3 * j + i
            tris += [[a, a + 1, a + 4], [a, a + 4, a + 3]]
    if flip is not None:
        tris[flip] = tris[flip][::-1]
    groups = {"bottom": [[0, 1], [1, 2]], "top": [[6, 7], [7, 8]], "left": [[0, 3], [3, 6]], "right": [[2, 5], [5, 8]]}
    _write_msh(path, pts, tris, groups)
    return {"mesh": {"file": path.name}, "material": {"E": 1000.0, "nu": 0.3, "yield_stress": 10.0, "hardening": 100.0},
            "boundary": {"clamped": ["top"], "contact": ["bottom"], "fix_component": {"x": ["left", "right"]}},
            "obstacle": {"shape": "flat"}, "load": {"force": 1.0}}


def test_gmsh_file_with_unused_node_is_read(tmp_path):
    import elastoplast as ep

    data = _unit_square(tmp_path / "sq.msh")
    problem = ep.problem_from_dict(data, base_dir=tmp_path)
    assert problem.mesh.n_nodes == 9  # the unused node is dropped
    disc = ep.discretize(problem)
    assert disc.volumes.sum() == pytest.approx(2.0)  # the area of [0,2]x[0,1]


def test_bad_elements_are_refused(tmp_path, capsys):
    data = _unit_square(tmp_path / "sq.msh", collapse=True)
    code = main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "mesh" in err and "degenerate" in err


def test_an_element_listed_clockwise_is_reoriented(tmp_path, capsys):
    """One triangle listed the other way round is the same geometry (issue 39: a fold is
    what stays refused, tests/test_bad_input4.py): read with a warning, solved."""
    data = _unit_square(tmp_path / "sq.msh", flip=3)
    code = main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 0 and "1 of 8 elements were listed with the opposite orientation" in capsys.readouterr().err


def test_perfect_plasticity_warns_and_reports_the_limit_load(tmp_path, capsys):
    """H = 0 above the limit load: no admissible stress field carries F.

    A column of width w with free sides on a flat punch, clamped on top. The
    frictionless punch and the free sides exert no horizontal force, so the
    horizontal stress integrates to zero across any vertical cut except for
    what shear (at most k = sigma_y / sqrt 3 by von Mises) brings from the top;
    with |sigma_xx - sigma_yy| <= 2k the load is bounded by a few k w, nodal
    equilibrium included. F = 1000 sigma_y w is far beyond. (A clamped, confined
    block would not do: hydrostatic pressure carries any load, and P1 triangles
    lock under plastic incompressibility.)
    """
    sigma_y = 250.0
    data = {"mesh": {"generator": "rectangle", "size": [1.0, 4.0], "divisions": [4, 8], "contact_radius": 1.0,
                     "pattern": "crossed"},  # P1 triangles two per square lock: refused with H = 0
            "material": {"E": 200e3, "nu": 0.3, "yield_stress": sigma_y, "hardening": 0.0},
            "boundary": {"clamped": ["top"], "contact": ["bottom"]},
            "obstacle": {"shape": "flat"}, "load": {"force": 1000 * sigma_y * 1.0}}
    code = main(["solve", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert "warning" in err and "perfect plasticity" in err
    assert "limit load" in err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["status"] == "infeasible"
    # below the limit load the same column is solved: F = k w, a third of the bound
    data["load"]["force"] = sigma_y / 3**0.5
    assert main(["solve", str(write_toml(tmp_path / "q.toml", data)), "--out", str(tmp_path / "o2"), "--quiet"]) == 0


def test_a_warning_during_a_progress_bar_gets_a_line_of_its_own(capsys):
    """The local bound warns (e.g. that it drops its descent) while its bar is drawn: the
    warning must not be glued to the end of the bar's line."""
    import re
    import sys

    from tqdm import tqdm

    from elastoplast.cli.main import _show_warning

    bar = tqdm(total=10, desc="local lower bound", file=sys.stderr, mininterval=0)
    bar.update(3)
    _show_warning("the sweeps alone run", UserWarning, "f.py", 1)
    bar.close()
    pieces = re.split(r"[\r\n]", capsys.readouterr().err)
    assert "warning: the sweeps alone run" in pieces, pieces
