"""The `bounds`, `limit` and `adapt` commands (issues 10 and 11), called through
``main(argv)``: what they print and write, and how they refuse bad input."""

from __future__ import annotations

import json
import math

import meshio
import numpy as np
import pytest

from elastoplast.adapt.records import AdaptOptions
from elastoplast.adapt.loop import adapt
from elastoplast.cli.main import main
from elastoplast.mesh.base import read_mesh

from conftest import build
from test_cli import small_cylinder, write_toml

SIGMA_Y = 250.0
K = SIGMA_Y / math.sqrt(3.0)


def strict_json(path):
    def refuse(constant):
        raise ValueError(constant)

    return json.loads(path.read_text(), parse_constant=refuse)


def half_punch(divisions=(10, 5), hardening=0.0) -> dict:
    """A flat rigid punch of half-width 1 on a half model (symmetry plane x = 0),
    crossed pattern: Prandtl's limit load of the half model is (2 + pi) k * 1
    (docs/validation.md), for a block large enough to hold his field."""
    return {"mesh": {"generator": "rectangle", "size": [10.0, 5.0], "divisions": list(divisions), "grading": 1.5,
                     "contact_radius": 1.0, "pattern": "crossed", "origin": [0.0, 0.0], "contact_center": [0.0]},
            "material": {"E": 200000.0, "nu": 0.3, "yield_stress": SIGMA_Y, "hardening": hardening},
            "boundary": {"clamped": ["xmax", "top"], "contact": ["contact"], "fix_component": {"x": ["xmin"]}},
            "obstacle": {"shape": "flat"}, "load": {"force": 100.0}}


# ---------------------------------------------------------------------------
# bounds
# ---------------------------------------------------------------------------


def test_bounds_command_reports_a_certified_bracket(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", small_cylinder())
    assert main(["bounds", str(problem), "--out", str(tmp_path / "b"), "--quiet"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("energy in [") and "certified" in line
    s = strict_json(tmp_path / "b" / "summary.json")
    lo, hi = s["energy_lower"], s["energy_upper"]
    assert s["bounds_certified"] is True
    assert lo <= hi
    # the definitions of the issue, checked against each other
    assert s["energy_gap_rel"] == pytest.approx((hi - lo) / abs(hi), rel=1e-12)
    assert s["stress_error_bound"] == pytest.approx(math.sqrt(2 * (hi - lo)), rel=1e-12)
    # the discrete solution's energy value(D) = Pi(u_h, U_h) lies above the lower bound
    # (weak duality with the P1 interpolant of psi, docs/bounds.md)
    assert s["value_D"] >= lo
    assert s["U_lower"] <= s["U_upper"]
    # the VTU carries the local gap on the elements and on the contact facets
    m = meshio.read(tmp_path / "b" / "solution.vtu")
    types = [b.type for b in m.cells]
    assert types == ["triangle", "line"]
    gap_el, gap_f = m.cell_data["gap"]
    assert gap_el.size == m.cells[0].data.shape[0] and gap_f.size == m.cells[1].data.shape[0]
    # the local terms sum to the gap (each is an exact integral)
    assert gap_el.sum() + gap_f.sum() == pytest.approx(hi - lo, rel=1e-9)


def test_bounds_refuses_h0_above_the_limit_load_and_writes_nothing(tmp_path, capsys):
    """H = 0 with F three times Prandtl's load, above the continuum limit load (and
    above the discrete one of (2.1), which the conic reference proves infeasible):
    there is nothing to bound. Exit 2 naming load.force, nothing written."""
    data = half_punch()
    data["load"]["force"] = 3 * (2 + math.pi) * K
    code = main(["bounds", str(write_toml(tmp_path / "p.toml", data)), "--out", str(tmp_path / "b"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: load.force:") and "limit load" in err[-1], err
    assert not (tmp_path / "b").exists()


def test_bounds_refuses_a_mesh_too_large_for_the_lower_bound(tmp_path, capsys, monkeypatch):
    """The global program's size limit (its choice: --lower global); the local bound, which
    "auto" takes on such a mesh, has none but is refused by its memory estimate."""
    from elastoplast.limits import MEMORY_ENV

    data = small_cylinder()
    data["mesh"]["divisions"] = [400, 200]  # 160,000 triangles > the 2D limit
    problem = str(write_toml(tmp_path / "p.toml", data))
    code = main(["bounds", problem, "--lower", "global", "--out", str(tmp_path / "b"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: mesh:") and "lower bound" in err[-1], err
    assert "equilibrium-element" in err[-1] and "limited to 100,000" in err[-1], err
    assert not (tmp_path / "b").exists()
    monkeypatch.setenv(MEMORY_ENV, "1G")  # 160,000 x LOCAL_BOUND_BYTES_PER_ELEMENT[2] = 1.9 GB
    code = main(["bounds", problem, "--out", str(tmp_path / "b"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: mesh: the local lower bound") and "needs about" in err[-1], err
    assert not (tmp_path / "b").exists()


# ---------------------------------------------------------------------------
# limit
# ---------------------------------------------------------------------------


def test_limit_command_brackets_prandtl(tmp_path, capsys):
    """F_lower <= (2 + pi) k * (half-width 1) <= F_upper on the half punch."""
    code = main(["limit", str(write_toml(tmp_path / "p.toml", half_punch())), "--out", str(tmp_path / "l"),
                 "--quiet"])
    assert code == 0
    s = strict_json(tmp_path / "l" / "summary.json")
    prandtl = (2 + math.pi) * K * 1.0
    assert s["certified"] is True
    assert s["F_lower"] <= prandtl <= s["F_upper"]
    assert s["ratio"] == pytest.approx(s["F_upper"] / s["F_lower"], rel=1e-12)
    assert "<= F_c <=" in capsys.readouterr().out


def test_limit_refuses_hardening(tmp_path, capsys):
    code = main(["limit", str(write_toml(tmp_path / "p.toml", half_punch(hardening=1000.0))),
                 "--out", str(tmp_path / "l"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: material.hardening:"), err


def test_limit_refuses_a_bad_order(tmp_path, capsys):
    code = main(["limit", str(write_toml(tmp_path / "p.toml", half_punch())), "--order", "3",
                 "--out", str(tmp_path / "l"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: --order:"), err


# ---------------------------------------------------------------------------
# adapt
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def coarse_cylinder():
    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]
    return build(data).problem


def test_adapt_stops_at_rtol_and_refines_where_the_gap_is(coarse_cylinder):
    run = adapt(coarse_cylinder, AdaptOptions(rtol=0.1, bracket="never", compare_uniform=False))
    assert run.reason.startswith("relative gap") and run.final.gap_rel <= 0.1
    assert all(s.certified for s in run.steps)
    sizes = [s.n_elements for s in run.steps]
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes)  # every step refined something
    # nested meshes: the contact zone and the groups are kept
    first, last = run.meshes[0], run.meshes[-1]
    assert set(first.groups) == set(last.groups)
    area = lambda m, g: np.abs(np.diff(m.points[m.groups[g]][:, :, 0], axis=1)).sum()  # noqa: E731
    assert area(last, "contact") == pytest.approx(area(first, "contact"), rel=1e-12)
    # the gap falls from step to step on nested meshes here (not a theorem, but the bound
    # on a refined mesh can only use more fields: the lower bound never decreases)
    lowers = [s.energy_lower for s in run.steps]
    assert all(b >= a - 1e-9 * abs(a) for a, b in zip(lowers, lowers[1:]))


@pytest.mark.parametrize("budget,reason", [
    ({"max_iter": 2}, "max_iter"),
    ({"max_elements": 300}, "max_elements"),
    ({"time_limit": 1e-3}, "time_limit"),
])
def test_adapt_stops_on_each_budget(coarse_cylinder, budget, reason):
    run = adapt(coarse_cylinder, AdaptOptions(rtol=1e-6, bracket="never", compare_uniform=False, **budget))
    assert reason in run.reason, run.reason
    if "max_elements" in budget:
        assert run.final.n_elements <= 300


def test_adapt_command_writes_table_plot_meshes_and_final_solution(tmp_path, capsys):
    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]
    out = tmp_path / "a"
    code = main(["adapt", str(write_toml(tmp_path / "p.toml", data)), "--rtol", "0.1", "--bracket", "final",
                 "--out", str(out), "--quiet"])
    printed = capsys.readouterr().out.strip().splitlines()
    assert code == 0
    steps = [line for line in printed if line.startswith("step")]
    record = strict_json(out / "adapt.json")
    assert len(record["adaptive"]) + len(record["uniform"]) == len(steps)
    final = record["adaptive"][-1]
    assert final["gap_rel"] <= 0.1 and final["U_lower"] <= final["U_upper"]
    assert (out / "gap.png").stat().st_size > 0 and (out / "adapt.md").read_text().startswith("| run |")
    meshes = sorted((out / "meshes").iterdir())
    assert len(meshes) == len(record["adaptive"])
    again = read_mesh(meshes[-1])  # every mesh reads back with its groups
    assert again.n_elements == final["n_elements"] and "contact" in again.groups
    s = strict_json(out / "summary.json")
    assert s["energy_gap_rel"] == pytest.approx(final["gap_rel"], rel=1e-12)
    rows = [r for r in record["adaptive"] if r["certified"]]  # the run's bracket: the best of each side
    assert s["run_energy_lower"] == max(r["energy_lower"] for r in rows)
    assert s["run_energy_upper"] == min(r["energy_upper"] for r in rows)
    assert s["run_gap_rel"] <= s["energy_gap_rel"] * (1 + 1e-12)


def test_adapt_refuses_bad_options(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", small_cylinder())
    for flags, field in ((["--rtol", "0"], "--rtol"), (["--theta", "1.5"], "--theta"),
                         (["--min-growth", "0.5"], "--min-growth"), (["--min-growth", "nan"], "--min-growth"),
                         (["--max-elements", "-5"], "--max-elements"), (["--method", "nope"], "--method")):
        code = main(["adapt", str(problem), "--out", str(tmp_path / "a"), "--quiet", *flags])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and err[-1].startswith(f"error: {field}:"), (flags, err)
        assert not (tmp_path / "a").exists()
