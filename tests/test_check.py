"""``elastoplast check``: the KKT certificate of an answer computed anywhere
(elastoplast/cli/check.py, io/answers.py, studies/answer.py), on a small 2D problem (861 nodes, 1600 triangles)."""

from __future__ import annotations

import json
import pickle
import warnings
from pathlib import Path
from types import MappingProxyType

import meshio
import numpy as np
import pytest

import elastoplast as ep
from elastoplast.cli.check import run_check
from elastoplast.io.answers import read_answer
from elastoplast.studies.answer import certify_answer
from elastoplast.cli.commands import COMMANDS
from elastoplast.cli.main import main
from elastoplast.errors import InputError

from conftest import build, cylinder_dict, sphere_quarter_dict
from test_cli import write_toml

DIVISIONS = (40, 20)
#: the command is reached through main once cli/main.py wires it
WIRED = "check" in COMMANDS


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The problem file, its discretisation and Newton's answer (an independent path:
    Newton on (D), not the conic reference)."""
    folder = tmp_path_factory.mktemp("check")
    data = cylinder_dict(divisions=DIVISIONS)
    toml = write_toml(folder / "cylinder.toml", data)
    disc = build(data)
    newton = ep.solve(disc, "newton", progress=False)
    assert newton.converged
    return {"folder": folder, "toml": toml, "data": data, "disc": disc, "newton": newton}


def npz(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


def with_field_data_U(vtu: Path, U: float) -> None:
    """Add field data ``U`` to a VTU (meshio reads VTU field data but does not write it)."""
    text = vtu.read_text()
    block = (f'<UnstructuredGrid>\n<FieldData>\n<DataArray type="Float64" Name="U" NumberOfTuples="1" '
             f'format="ascii">{U!r}</DataArray>\n</FieldData>')
    vtu.write_text(text.replace("<UnstructuredGrid>", block, 1))


def report_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


RESIDUALS = ("constitutive", "constitutive_max", "equilibrium", "force_balance", "sign", "penetration",
             "complementarity", "dirichlet")


# ----------------------------------------------------------------------------
# (1) an independent answer certifies: npz with u and U only, the solution.vtu of a solve
# ----------------------------------------------------------------------------


def test_newton_answer_with_u_and_U_only_certifies(case, tmp_path, capsys):
    answer = npz(tmp_path / "newton.npz", u=case["newton"].u, U=case["newton"].U)
    assert run_check(case["toml"], answer) == 0
    out = capsys.readouterr().out
    lines = report_lines(out)
    assert len(lines) == len(RESIDUALS) + 1  # one line per residual, then the verdict
    for name, line in zip(RESIDUALS, lines):
        assert line.split()[0] == name and line.endswith("ok")
    assert lines[-1].startswith("certified: every KKT residual at most tol 1e-06")


def test_answer_with_its_own_stresses_certifies(case, tmp_path, capsys):
    s = case["newton"]
    answer = npz(tmp_path / "full.npz", u=s.u, U=s.U, sigma=s.sigma, xi=s.xi)
    assert run_check(case["toml"], answer, quiet=True) == 0
    assert capsys.readouterr().err == ""  # quiet: no context line


def test_solution_vtu_written_by_solve_certifies(case, tmp_path, capsys):
    """The conic reference through the command line, its solution.vtu checked: U from
    the summary.json beside it; and a VTU carrying U as field data, alone in its folder."""
    assert main(["solve", str(case["toml"]), "--out", "res", "--quiet"]) == 0
    vtu = tmp_path / "res" / "solution.vtu"
    assert run_check(case["toml"], vtu) == 0
    U = json.loads((tmp_path / "res" / "summary.json").read_text())["U"]
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "answer.vtu").write_bytes(vtu.read_bytes())
    with pytest.raises(InputError, match=r"^ANSWER\.U: missing"):
        run_check(case["toml"], alone / "answer.vtu")
    with_field_data_U(alone / "answer.vtu", U)
    assert read_answer(alone / "answer.vtu", case["disc"])["U"] == U
    assert run_check(case["toml"], alone / "answer.vtu") == 0
    capsys.readouterr()


def test_vtu_in_another_node_order_is_matched_by_position(case, tmp_path, capsys):
    disc, s = case["disc"], case["newton"]
    perm = np.random.default_rng(1).permutation(disc.mesh.n_nodes)
    inverse = np.argsort(perm)
    points = np.column_stack([disc.mesh.points, np.zeros(disc.mesh.n_nodes)])[perm]
    disp = np.column_stack([s.u, np.zeros(disc.mesh.n_nodes)])[perm]
    vtu = tmp_path / "shuffled.vtu"
    meshio.write(vtu, meshio.Mesh(points, [("triangle", inverse[disc.mesh.cells])], point_data={"displacement": disp}))
    with_field_data_U(vtu, s.U)
    np.testing.assert_array_equal(read_answer(vtu, disc)["u"], s.u)
    assert run_check(case["toml"], vtu) == 0
    assert "another order; matched by position" in capsys.readouterr().err
    other = tmp_path / "moved.vtu"  # the same count of points, elsewhere: another mesh
    meshio.write(other, meshio.Mesh(points + [1.0, 0.0, 0.0], [("triangle", inverse[disc.mesh.cells])],
                                    point_data={"displacement": disp}))
    with_field_data_U(other, s.U)
    with pytest.raises(InputError, match=r"^ANSWER\.points: .* not the 861 nodes"):
        read_answer(other, disc)


def test_3d_answer_with_stresses(tmp_path, capsys):
    """3D: six Mandel components; the residuals equal those of the solve's own certificate."""
    data = sphere_quarter_dict()
    toml = write_toml(tmp_path / "quarter.toml", data)
    disc = build(data)
    s = ep.solve(disc, "newton", progress=False)
    assert run_check(toml, npz(tmp_path / "q.npz", u=s.u, U=s.U, sigma=s.sigma, xi=s.xi)) == 0
    kkt = certify_answer(disc, read_answer(tmp_path / "q.npz", disc), tol=1e-6).kkt
    assert kkt == s.kkt
    with pytest.raises(InputError, match=r"^ANSWER\.sigma: expected \(1080, 6\), got \(1080, 4\); 3D stresses "
                                         r"have 6 Mandel components"):
        run_check(toml, npz(tmp_path / "q4.npz", u=s.u, U=s.U, sigma=s.sigma[:, :4], xi=s.xi))
    capsys.readouterr()


# ----------------------------------------------------------------------------
# (2) the same answer scaled by 1.01 is refused
# ----------------------------------------------------------------------------


def test_answer_scaled_by_one_percent_is_refused(case, tmp_path, capsys):
    """Why (u, U) -> 1.01 (u, U) must fail, residual by residual (stresses by the return mapping):

    * force_balance = 0.01 exactly here: the return mapping is positively homogeneous on
      elastic elements (R(1.01 eps) = 1.01 R(eps) below the yield surface), and every
      element at a contact node stays elastic (yield starts beneath the surface, as in
      Hertz contact), so the implied contact forces N r are 1.01 lambda and sum to 1.01 F;
    * penetration = 0.01 max_active psi_i / (1.01 delta): an active node's gap
      g_i = u_d + psi_i - U = 0 becomes 1.01 g_i - 0.01 psi_i = -0.01 psi_i;
    * equilibrium > 0: on the plastic elements R(1.01 eps) != 1.01 R(eps) (the yield
      surface does not scale), so r is no longer balanced off the contact dofs.
    Each is orders of magnitude above tol = 1e-6."""
    disc, s = case["disc"], case["newton"]
    answer = npz(tmp_path / "scaled.npz", u=1.01 * s.u, U=1.01 * s.U)
    assert run_check(case["toml"], answer) == 1
    lines = report_lines(capsys.readouterr().out)
    assert lines[-1].startswith("NOT certified: equilibrium, force_balance, penetration")
    failed = {line.split()[0] for line in lines[:-1] if line.endswith("FAIL")}
    assert {"equilibrium", "force_balance", "penetration"} <= failed

    kkt = certify_answer(disc, read_answer(answer, disc), tol=1e-6).kkt
    at_contact = np.isin(disc.mesh.cells, disc.contact_nodes).any(axis=1)
    assert not s.plastic[at_contact].any() and s.plastic.any()
    assert kkt.force_balance == pytest.approx(0.01, rel=1e-9)
    gap = disc.N @ disc.free_displacement(s.u) + disc.psi - s.U
    delta = max(abs(s.U), np.abs(s.u).max())
    assert np.all(np.abs(gap[s.active]) <= 1e-12 * delta)
    assert kkt.penetration == pytest.approx(0.01 * disc.psi[s.active].max() / (1.01 * delta), rel=1e-6)
    assert kkt.penetration > 1e3 * 1e-6 and kkt.equilibrium > 1e2 * 1e-6


def test_tolerance_from_the_flag_or_the_problem_file(case, tmp_path, capsys):
    """A 0.1% scaling passes tol 1e-2 (the file's [solver] tol), not 1e-6 (--tol)."""
    s = case["newton"]
    answer = npz(tmp_path / "close.npz", u=1.001 * s.u, U=1.001 * s.U)
    loose = write_toml(tmp_path / "loose.toml", {**case["data"], "solver": {"method": "newton", "tol": 1e-2}})
    assert run_check(loose, answer) == 0
    assert run_check(loose, answer, tol=1e-6) == 1
    assert run_check(case["toml"], answer) == 1  # the default 1e-6
    with pytest.raises(InputError, match=r"^--tol: must be a number in \[1e-13, 0\.01\]"):
        run_check(case["toml"], answer, tol=5.0)
    capsys.readouterr()


def test_dirichlet_judges_u_as_given(case, tmp_path, capsys):
    disc, s = case["disc"], case["newton"]
    u = s.u.copy().reshape(-1)
    u[disc.fixed[0]] = 0.01 * abs(s.U)
    assert run_check(case["toml"], npz(tmp_path / "moved.npz", u=u.reshape(s.u.shape), U=s.U)) == 1
    line = next(x for x in report_lines(capsys.readouterr().out) if x.startswith("dirichlet"))
    assert float(line.split()[1]) == pytest.approx(0.01, rel=1e-2) and line.endswith("FAIL")


# ----------------------------------------------------------------------------
# (3) malformed answers: one line naming the array (exit 2 through main)
# ----------------------------------------------------------------------------


def malformed(s) -> dict:
    nan = s.u.copy()
    nan[17, 1] = np.nan
    return {
        "wrong node count": ({"u": s.u[:-1], "U": s.U},
                             "ANSWER.u: expected (861, 2), got (860, 2); the problem's mesh has 861 nodes"),
        "NaN": ({"u": nan, "U": s.U}, "ANSWER.u: 1 NaN or infinite value(s) (first at row 17)"),
        "missing U": ({"u": s.u}, "ANSWER.U: missing (the .npz holds u)"),
        "3 columns in 2D": ({"u": np.column_stack([s.u, s.u[:, :1]]), "U": s.U},
                            "ANSWER.u: expected (861, 2), got (861, 3)"),
        "U not a number": ({"u": s.u, "U": np.array(["a"])}, "ANSWER.U: expected real numbers"),
        "sigma without xi": ({"u": s.u, "U": s.U, "sigma": s.sigma}, "ANSWER.xi: missing (sigma is given"),
        "sigma of 3 components": ({"u": s.u, "U": s.U, "sigma": s.sigma[:, :3], "xi": s.xi},
                                  "ANSWER.sigma: expected (1600, 4), got (1600, 3)"),
    }


@pytest.mark.parametrize("kind", ["wrong node count", "NaN", "missing U", "3 columns in 2D", "U not a number",
                                  "sigma without xi", "sigma of 3 components"])
def test_malformed_answer_names_the_array(case, tmp_path, kind, capsys):
    arrays, message = malformed(case["newton"])[kind]
    answer = npz(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError) as info:
        run_check(case["toml"], answer)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)
    assert capsys.readouterr().out == ""  # refused before any report
    if WIRED:
        assert main(["check", str(case["toml"]), str(answer)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith(f"error: {message}")


@pytest.mark.parametrize("content, message", [
    (None, "ANSWER: answer file not found"),
    (b"", "is empty"),
    (b"not an answer", "is neither an .npz"),
    (b"PK\x03\x04 truncated", "ANSWER: cannot read"),
])
def test_unreadable_answer_file(case, tmp_path, content, message):
    path = tmp_path / "answer.dat"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message):
        run_check(case["toml"], path)


# ----------------------------------------------------------------------------
# (4) --bounds: the bracket contains the conic reference's energy; (5) nothing written without --out
# ----------------------------------------------------------------------------


def test_bounds_bracket_contains_the_conic_energy(case, tmp_path, capsys):
    disc, s = case["disc"], case["newton"]
    conic = ep.solve(disc, "conic", progress=False)
    answer = npz(tmp_path / "newton.npz", u=s.u, U=s.U)
    assert run_check(case["toml"], answer, bounds=True, out="out", quiet=True) == 0
    lines = report_lines(capsys.readouterr().out)
    assert lines[-2].startswith("energy in [") and lines[-2].endswith("; certified")
    assert lines[-1].startswith("certified:") and lines[-1].endswith("-> out/summary.json")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["bounds_certified"] and summary["check"]["certified"] and summary["method"] == "answer"
    assert summary["energy_lower"] <= conic.value_D <= summary["energy_upper"]
    assert summary["U_lower"] <= s.U <= summary["U_upper"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [".elastoplast-output.json", "solution.vtu",
                                                                    "summary.json"]
    # the upper bound is that of the answer's own field
    assert summary["energy_upper"] == pytest.approx(ep.upper_bound(disc, (s.u, s.U)).Pi, rel=1e-12)


def test_nothing_is_written_without_out(case, tmp_path, capsys):
    answer = npz(tmp_path / "newton.npz", u=case["newton"].u, U=case["newton"].U)
    before = {p: p.stat().st_mtime_ns for p in [*tmp_path.rglob("*"), *case["folder"].rglob("*")]}
    assert run_check(case["toml"], answer) == 0
    assert run_check(case["toml"], npz(tmp_path / "scaled.npz", u=1.01 * case["newton"].u, U=case["newton"].U)) == 1
    after = {p: p.stat().st_mtime_ns for p in [*tmp_path.rglob("*"), *case["folder"].rglob("*")]}
    assert set(after) - set(before) == {tmp_path / "scaled.npz"} and all(after[p] == t for p, t in before.items())
    capsys.readouterr()


@pytest.mark.skipif(not WIRED, reason="'check' is not wired into cli/main.py yet")
def test_through_main(case, tmp_path, capsys):
    s = case["newton"]
    good = npz(tmp_path / "good.npz", u=s.u, U=s.U)
    assert main(["check", str(case["toml"]), str(good), "--quiet"]) == 0
    assert main(["check", str(case["toml"]), str(npz(tmp_path / "bad.npz", u=1.01 * s.u, U=1.01 * s.U))]) == 1
    assert main(["check", str(case["toml"]), str(good), "--tol", "5"]) == 2
    assert main(["check", str(case["toml"]), str(good), "--out", "out", "--quiet"]) == 0
    assert (tmp_path / "out" / "summary.json").is_file()
    capsys.readouterr()


# ----------------------------------------------------------------------------
# (6) the adversarial pass: each input it found, refused or judged with a readable message
# ----------------------------------------------------------------------------


def vtu_of(path: Path, disc, u, U=None) -> Path:
    """A VTU answer: the mesh's points and ``displacement``, field data U when given."""
    points = np.column_stack([disc.mesh.points, np.zeros(disc.mesh.n_nodes)])
    disp = np.column_stack([u, np.zeros(disc.mesh.n_nodes)])
    meshio.write(path, meshio.Mesh(points, [("triangle", disc.mesh.cells)], point_data={"displacement": disp}))
    if U is not None:
        with_field_data_U(path, U)
    return path


def test_huge_summary_json_is_refused_unread(case, tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    vtu = vtu_of(folder / "solution.vtu", case["disc"], case["newton"].u)
    with open(folder / "summary.json", "wb") as fh:  # sparse: 2 GiB on paper, nothing on disk
        fh.truncate(2 * 2**30)
    with pytest.raises(InputError, match=r"^ANSWER\.U: summary\.json .* has 2 GiB, more than the 4 MiB a "
                                         r"summary\.json may have$"):
        read_answer(vtu, case["disc"])


@pytest.mark.parametrize("n_nodes, message", [
    ('"861"', "n_nodes must be an integer (the node count of the solve's mesh), got '861'"),
    ("true", "n_nodes must be an integer (the node count of the solve's mesh), got True"),
    ("860", "belongs to a mesh of 860 nodes, not this problem's 861"),
])
def test_summary_json_n_nodes_must_be_an_integer(case, tmp_path, n_nodes, message):
    vtu = vtu_of(tmp_path / "solution.vtu", case["disc"], case["newton"].u)
    (tmp_path / "summary.json").write_text(f'{{"U": {case["newton"].U!r}, "n_nodes": {n_nodes}}}')
    with pytest.raises(InputError) as info:
        read_answer(vtu, case["disc"])
    assert info.value.field == "ANSWER.U" and message in info.value.message


def test_huge_finite_answer_is_refused_without_numpy_warnings(case, tmp_path, capsys):
    u = case["newton"].u
    huge = npz(tmp_path / "huge.npz", u=u * 0 + 1e300, U=1e300)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy RuntimeWarning (overflow, invalid value) fails the test
        with pytest.raises(InputError, match=r"^ANSWER\.u: values up to 1e\+300 overflow the strains \(the mesh is "
                                             r"40 across, its shortest edge .*, E = 200000\)"):
            run_check(case["toml"], huge)
        with pytest.raises(InputError, match=r"^ANSWER\.sigma: values up to 1e\+300 overflow"):
            certify_answer(case["disc"], {"u": u, "U": 0.0, "sigma": np.full((1600, 4), 1e300),
                                          "xi": np.zeros(1600)}, 1e-6)
        # large but below the overflow: judged, not certified, for the right reason
        sol = certify_answer(case["disc"], read_answer(npz(tmp_path / "big.npz", u=u * 1e80, U=1e80), case["disc"]),
                             1e-6)
    assert not sol.converged and "non-finite" not in sol.message and "above tol" in sol.message
    assert capsys.readouterr().out == ""
    if WIRED:
        assert main(["check", str(case["toml"]), str(huge)]) == 2
        assert capsys.readouterr().err.strip().splitlines()[-1].startswith("error: ANSWER.u: values up to 1e+300")


def test_out_holding_the_answer_is_refused(case, tmp_path, capsys):
    assert main(["solve", str(case["toml"]), "--out", "s3", "--quiet"]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in (tmp_path / "s3").iterdir()}
    for out in ("s3", tmp_path / "s3", "s3/../s3"):
        with pytest.raises(InputError, match=r"^--out: .* holds the answer .*solution\.vtu and the summary\.json "
                                             r"beside it\), which the results would replace"):
            run_check(case["toml"], "s3/solution.vtu", out=out)
    assert {p.name: p.read_bytes() for p in (tmp_path / "s3").iterdir()} == before
    assert capsys.readouterr().out == ""
    if WIRED:
        assert main(["check", str(case["toml"]), "s3/solution.vtu", "--out", "s3"]) == 2
        assert {p.name: p.read_bytes() for p in (tmp_path / "s3").iterdir()} == before


def test_content_decides_the_format(case, tmp_path, capsys):
    s = case["newton"]
    good = npz(tmp_path / "good.npz", u=s.u, U=s.U)
    (tmp_path / "good.VTU").write_bytes(good.read_bytes())
    assert run_check(case["toml"], tmp_path / "good.VTU", quiet=True) == 0
    assert "good.VTU is an .npz (a zip archive) whatever its suffix says" in capsys.readouterr().err
    vtu = vtu_of(tmp_path / "v.vtu", case["disc"], s.u, s.U)
    (tmp_path / "answer.npz").write_bytes(vtu.read_bytes())
    assert read_answer(tmp_path / "answer.npz", case["disc"])["format"] == "vtu"
    (tmp_path / "text.vtu").write_text("displacement 1 2 3\n")
    with pytest.raises(InputError, match=r"^ANSWER: cannot read .*text\.vtu as a VTU: it is not an XML file"):
        read_answer(tmp_path / "text.vtu", case["disc"])
    (tmp_path / "other.vtu").write_text('<?xml version="1.0"?>\n<VTKFile type="PolyData"></VTKFile>\n')
    with pytest.raises(InputError, match=r"^ANSWER: cannot read .*other\.vtu as a VTU: ") as info:
        read_answer(tmp_path / "other.vtu", case["disc"])
    assert "SystemExit" not in str(info.value) and "Error:" not in str(info.value)


def test_empty_U_field_in_a_vtu_gives_a_clean_message(case, tmp_path):
    vtu = vtu_of(tmp_path / "a.vtu", case["disc"], case["newton"].u)
    vtu.write_text(vtu.read_text().replace("<UnstructuredGrid>", '<UnstructuredGrid>\n<FieldData>\n<DataArray '
                                           'type="Float64" Name="U" NumberOfTuples="1" format="ascii"></DataArray>\n'
                                           "</FieldData>", 1))
    with pytest.raises(InputError) as info:
        read_answer(vtu, case["disc"])
    assert str(info.value).endswith("as a VTU: malformed VTU content (a DataArray that is empty, truncated or of "
                                    "another size than declared, or a missing attribute)")
    assert "NoneType" not in str(info.value) and "AttributeError" not in str(info.value)


def test_python_entry_points_name_their_arguments(case, tmp_path):
    disc, s = case["disc"], case["newton"]
    good = npz(tmp_path / "good_full.npz", u=s.u, U=s.U, sigma=s.sigma, xi=s.xi)
    for call, message in [
        (lambda: certify_answer(disc, {"u": np.zeros(3), "U": 0.0}, 1e-6), "ANSWER.u: expected (861, 2), got (3,)"),
        (lambda: certify_answer(disc, {"u": s.u, "U": np.zeros(2)}, 1e-6), "ANSWER.U: expected a single number"),
        (lambda: certify_answer(disc, {"u": s.u}, 1e-6), "ANSWER.U: missing"),
        (lambda: certify_answer(disc, {"u": s.u, "U": "a"}, 1e-6), "ANSWER.U: expected real numbers"),
        (lambda: certify_answer(disc, {"u": s.u, "U": s.U}, None), "tol: must be a number in [1e-13, 0.01], got None"),
        (lambda: certify_answer(disc, [s.u, s.U], 1e-6), "answer: expected a Mapping"),
        (lambda: certify_answer(None, {"u": s.u, "U": s.U}, 1e-6), "disc: expected a Discretization"),
        (lambda: read_answer(good, None), "disc: expected a Discretization"),
    ]:
        with pytest.raises(InputError) as info:
            call()
        assert str(info.value).startswith(message)
    assert certify_answer(disc, read_answer(good, disc), 1e-6).converged


def test_3d_displacement_shape_is_said_once(tmp_path):
    disc = build(sphere_quarter_dict(divisions=(3, 3, 2)))
    n = disc.mesh.n_nodes
    vtu = tmp_path / "q.vtu"
    meshio.write(vtu, meshio.Mesh(disc.mesh.points, [("tetra", disc.mesh.cells)],
                                  point_data={"displacement": np.zeros((n, 2))}))
    with pytest.raises(InputError, match=rf"^ANSWER\.displacement: expected \({n}, 3\), got \({n}, 2\)$"):
        read_answer(vtu, disc)


def test_bounds_refusing_the_load_print_nothing(tmp_path, capsys):
    """H = 0 and F far above the limit load: refused (load.force) before the residual table."""
    data = cylinder_dict(divisions=(16, 8), hardening=0.0)
    data["load"]["force"] = 1e6
    toml = write_toml(tmp_path / "h0big.toml", data)
    with pytest.warns(UserWarning, match="perfect plasticity"):
        disc = build(data)
    answer = npz(tmp_path / "h0z.npz", u=np.zeros((disc.mesh.n_nodes, 2)), U=0.0)
    with pytest.warns(UserWarning), pytest.raises(InputError, match=r"^load\.force: .*above this mesh's lower-bound "
                                                                    r"limit load"):
        run_check(toml, answer, bounds=True)
    assert capsys.readouterr().out == ""


def test_article_of_the_file_kind(case, tmp_path):
    with pytest.raises(InputError, match=r"^ANSWER: .* is a directory, not an answer file$"):
        run_check(case["toml"], tmp_path)
    with pytest.raises(InputError, match=r"^ANSWER: expected a path to an answer file, got int$"):
        read_answer(3, case["disc"])


def test_discretization_survives_pickling(case):
    disc = case["disc"]
    again = pickle.loads(pickle.dumps(disc))
    assert isinstance(again.mesh.groups, MappingProxyType) and set(again.mesh.groups) == set(disc.mesh.groups)
    assert isinstance(again.problem.boundary.fix_component, MappingProxyType)
    for part in (disc.mesh, disc.problem, disc.problem.boundary):
        pickle.loads(pickle.dumps(part))
    sol = ep.solve(again, "newton", progress=False)
    assert sol.converged and sol.U == case["newton"].U
    np.testing.assert_array_equal(sol.u, case["newton"].u)
