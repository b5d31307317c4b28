"""Round trips of the exported conic programs (elastoplast/io/export.py, io/cbf.py).

Each exported file is read back by code that shares nothing with the writer (the CBF
reader parses text; this file converts the CBF program to Clarabel's form on its own
and reads the npz's arrays by their documented names), solved by a conic solver
outside the package's own methods, and judged twice:

* the solver's optimal value against ``Solution.value_S`` (``value_D`` for (D)) of
  ``ep.solve(disc, "conic")``: (S)'s optimum computed independently, by the package's
  own interior point on its own assembly, polished by Newton steps and certified at
  1e-14..1e-16;
* the answer mapped back to the problem's units against the KKT certificate.

Clarabel runs at its default tolerances (gap and feasibility 1e-8): the optimal values
agree to 2e-11..8e-10 relative (measured on these two meshes, (S) and (D), CBF and
npz), and the certificate's worst residual, the per-element constitutive one, is
2.6e-6..1.5e-5 (the package's own raw interior-point answer, ``polish=False``, scores
6.6e-6 and 2.3e-5 on the same problems: the dual displacements of an interior point
stopped at a 1e-8 gap carry that error into the worst element's strains; the
energy-norm residual is 5e-7..2.5e-6). Thresholds 1e-7 and 1e-4.

SCS runs at eps = 1e-5 (its default is 1e-4). It is a first-order splitting method:
it stops when its primal and dual residuals and its gap are below eps relative to the
data, so the displacements, read off its duals, are accurate to about eps, and the
certificate's per-element ratio amplifies that error in the worst element; where it
stops also varies with the matrices' sparsity pattern. Measured: optimal values within
3e-7..9e-6, certificates 1.5e-6..2.5e-4. Thresholds 1e-4 and 2e-3.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp
from conftest import build, cylinder_dict, sphere_quarter_dict

import elastoplast as ep
from elastoplast.errors import InputError
from elastoplast.io.cbf import read_cbf
from elastoplast.io.export import answer_from_solution, displacement_form, export, solution_from_answer, stress_form
from elastoplast.io.export_files import load_npz, read_sidecar
from elastoplast.io.store import resolve
from elastoplast.solvers.backends import solve_scs

CLARABEL_VALUE, CLARABEL_KKT = 1e-7, 1e-4
SCS_EPS, SCS_VALUE, SCS_KKT = 1e-5, 1e-4, 2e-3


@pytest.fixture(scope="module", params=["cylinder-2d", "quarter-sphere-3d"])
def case(request):
    """A small 2D cylinder (1600 triangles) and a small 3D quarter box (384 tetrahedra),
    with the certified reference of the package's own conic method."""
    data = cylinder_dict((40, 20)) if request.param == "cylinder-2d" else sphere_quarter_dict((4, 4, 4))
    disc = build(data)
    ref = ep.solve(disc, "conic", progress=False)
    assert ref.converged and ref.kkt.worst < 1e-12
    return disc, ref


def reference_value(ref: ep.Solution, form: str) -> float:
    return ref.value_S if form == "S" else ref.value_D


# ----------------------------------------------------------------------------
# an independent CBF -> Clarabel conversion (CBF: g = A x + b in K; Clarabel: A x + s = b)
# ----------------------------------------------------------------------------


def rotation(size: int) -> sp.csr_matrix:
    """``(a, b, v) -> ((a+b)/sqrt2, (a-b)/sqrt2, v)``: symmetric, orthogonal, maps the
    rotated cone 2ab >= |v|^2 onto the second-order cone."""
    h = 1.0 / np.sqrt(2.0)
    return sp.block_diag([sp.csr_matrix([[h, h], [h, -h]]), sp.identity(size - 2)], format="csr")


def cbf_to_clarabel(prog):
    """``(P, q, A, b, cones, y_of)``; ``y_of(z)`` returns the CBF duals of the rows."""
    A = prog.A.tocsr()
    n = prog.c.size
    zero, nonneg, soc = [], [], []  # (cbf rows or None, matrix, rhs, transform or None)
    start = 0
    for dom, size in prog.con_cones:
        rows = np.arange(start, start + size)
        start += size
        M, rhs = -A[rows], prog.b[rows]
        if dom == "L=":
            zero.append((rows, M, rhs, None))
        elif dom == "L+":
            nonneg.append((rows, M, rhs, None))
        elif dom == "Q":
            soc.append((rows, M, rhs, None))
        elif dom == "QR":
            T = rotation(size)
            soc.append((rows, T @ M, T @ rhs, T))
        else:
            raise AssertionError(f"unexpected row domain {dom}")
    start = 0
    for dom, size in prog.var_cones:
        cols = np.arange(start, start + size)
        start += size
        if dom == "L+":
            pick = sp.csr_matrix((np.ones(size), (np.arange(size), cols)), shape=(size, n))
            nonneg.append((None, -pick, np.zeros(size), None))
        else:
            assert dom == "F", dom
    blocks = zero + nonneg + soc
    cones = ([clarabel.ZeroConeT(sum(M.shape[0] for _, M, _, _ in zero))] if zero else []) + \
            ([clarabel.NonnegativeConeT(sum(M.shape[0] for _, M, _, _ in nonneg))] if nonneg else []) + \
            [clarabel.SecondOrderConeT(M.shape[0]) for _, M, _, _ in soc]
    A_cl = sp.vstack([M for _, M, _, _ in blocks], format="csc")
    b_cl = np.concatenate([r for _, _, r, _ in blocks])

    def y_of(z):
        y, at = np.zeros(prog.b.size), 0
        for rows, M, _, T in blocks:
            part = z[at:at + M.shape[0]]
            at += M.shape[0]
            if rows is not None:
                y[rows] = part if T is None else T @ part
        return y

    return sp.csc_matrix((n, n)), prog.c.copy(), A_cl, b_cl, cones, y_of


def clarabel_solve(P, q, A, b, cones):
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    res = clarabel.DefaultSolver(P, q, A, b, cones, settings).solve()
    assert str(res.status).split(".")[-1] == "Solved", res.status
    return np.asarray(res.x), np.asarray(res.z), float(res.obj_val)


# ----------------------------------------------------------------------------
# CBF
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("form", ["S", "D"])
def test_cbf_reads_back_bit_for_bit(case, form, tmp_path):
    disc, _ = case
    info = export(disc, tmp_path / "p.cbf", "cbf", form)
    text = info.path.read_text()
    assert [ln for ln in text.splitlines() if ln and not ln.startswith("#")][:2] == ["VER", "3"]
    back = read_cbf(info.path)
    built = (stress_form if form == "S" else displacement_form)(disc)
    mine = built.program
    assert back.sense == "MIN" and back.c0 == 0.0 and back.version == 3
    assert back.var_cones == mine.var_cones and back.con_cones == mine.con_cones
    np.testing.assert_array_equal(back.c, mine.c)
    np.testing.assert_array_equal(back.b, mine.b)
    assert abs(back.A - mine.A).max() == 0.0 and back.A.nnz == mine.A.nnz
    domains = {d for d, _ in back.con_cones}
    assert domains == ({"L=", "Q", "QR"} if form == "S" else {"L+", "Q", "QR"})
    assert sum(1 for d, _ in back.con_cones if d == "QR") == 1
    assert sum(1 for d, _ in back.con_cones if d == "Q") == disc.n_elements


@pytest.mark.parametrize("form", ["S", "D"])
def test_cbf_solved_by_clarabel(case, form, tmp_path):
    disc, ref = case
    info = export(disc, tmp_path / "p.cbf", "cbf", form)
    P, q, A, b, cones, y_of = cbf_to_clarabel(read_cbf(info.path))
    x, z, value = clarabel_solve(P, q, A, b, cones)
    expected = reference_value(ref, form)
    assert abs(value - expected) <= CLARABEL_VALUE * abs(expected)
    assert abs(value + reference_value(ref, "D" if form == "S" else "S")) <= CLARABEL_VALUE * abs(expected)
    answer = answer_from_solution(disc, x, y_of(z), read_sidecar(info.path))
    sol = solution_from_answer(disc, answer, method="cbf+clarabel")
    assert sol.kkt.worst <= CLARABEL_KKT, sol.kkt.as_dict()
    assert abs(reference_value(sol, form) - expected) <= 1e-6 * abs(expected)  # the functional at the answer
    assert abs(sol.U - ref.U) <= 1e-5 * abs(ref.U)


def test_cbf_reader_on_a_hand_written_file(tmp_path):
    """A file written by hand (comments, blank lines, a variable domain, a rotated cone, an
    objective constant) gives the arrays it says; keywords it does not read are refused."""
    path = tmp_path / "tiny.cbf"
    path.write_text("# min x0 + 2 x1 + 0.5 s.t. x0 + x1 = 1, 2 (x2)(x0) >= x1^2, x0 >= 0\nVER\n3\n\n"
                    "OBJSENSE\nMIN\n\nVAR\n3 2\nL+ 1\nF 2\n\nCON\n4 2\nL= 1\nQR 3\n\n"
                    "OBJACOORD\n2\n0 1.0\n1 2.0\n\nOBJBCOORD\n0.5\n\n"
                    "ACOORD\n5\n0 0 1.0\n0 1 1.0\n1 2 1.0\n2 0 1.0\n3 1 1.0\n\nBCOORD\n1\n0 -1.0\n")
    prog = read_cbf(path)
    np.testing.assert_array_equal(prog.c, [1.0, 2.0, 0.0])
    assert prog.c0 == 0.5 and prog.var_cones == [("L+", 1), ("F", 2)] and prog.con_cones == [("L=", 1), ("QR", 3)]
    np.testing.assert_array_equal(prog.A.toarray(), [[1, 1, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(prog.b, [-1.0, 0.0, 0.0, 0.0])
    path.write_text("VER\n3\n\nPSDVAR\n1\n2\n")
    with pytest.raises(InputError, match="PSDVAR"):
        read_cbf(path)
    path.write_text("VER\n3\n\nVAR\n3 1\nF 2\n")
    with pytest.raises(InputError, match="add up"):
        read_cbf(path)


# ----------------------------------------------------------------------------
# npz
# ----------------------------------------------------------------------------


def npz_data(path):
    """The arrays by their documented names, without the module's loader."""
    with np.load(path) as f:
        mats = {name: sp.csc_matrix((f[f"{name}_data"], f[f"{name}_indices"], f[f"{name}_indptr"]),
                                    shape=tuple(f[f"{name}_shape"])) for name in ("A", "P")}
        sizes = int(f["zero"]), int(f["nonnegative"]), [int(v) for v in f["second_order"]]
        return mats["P"], np.array(f["q"]), mats["A"], np.array(f["b"]), sizes, np.array(f["free_dofs"])


@pytest.mark.parametrize("form", ["S", "D"])
def test_npz_solved_by_clarabel_and_scs(case, form, tmp_path):
    disc, ref = case
    info = export(disc, tmp_path / "p.npz", "npz", form)
    meta = read_sidecar(info.path)
    P, q, A, b, (z, nn, soc), free = npz_data(info.path)
    np.testing.assert_array_equal(free, disc.free)
    assert P.nnz == 0 and A.shape == (z + nn + sum(soc), q.size) and b.size == A.shape[0]
    assert soc.count(disc.k) == disc.n_elements and len(soc) == disc.n_elements + 1
    assert nn == disc.n_contact and z == (disc.n_free + 1 if form == "S" else 0)
    cones = ([clarabel.ZeroConeT(z)] if z else []) + [clarabel.NonnegativeConeT(nn)] + \
            [clarabel.SecondOrderConeT(s) for s in soc]
    expected = reference_value(ref, form)

    x, y, value = clarabel_solve(P, q, A, b, cones)
    assert abs(value - expected) <= CLARABEL_VALUE * abs(expected)
    sol = solution_from_answer(disc, answer_from_solution(disc, x, y, meta), method="npz+clarabel")
    assert sol.kkt.worst <= CLARABEL_KKT, sol.kkt.as_dict()

    res = solve_scs(P, q, A, b, cones, eps=SCS_EPS, max_iters=20_000)
    assert res.status is ep.Status.CONVERGED, res.raw
    assert abs(res.objective - expected) <= SCS_VALUE * abs(expected)
    sol = solution_from_answer(disc, answer_from_solution(disc, res.x, res.z, meta), method="npz+scs")
    assert sol.kkt.worst <= SCS_KKT, sol.kkt.as_dict()

    loaded = load_npz(info.path)
    assert loaded["cones"] == {"z": z, "l": nn, "q": soc}
    assert abs(loaded["A"] - A).max() == 0.0


def test_npz_with_the_energy_in_P(case, tmp_path):
    """``energy="quadratic"``: the same (S) with the energy in P (no epigraph, no rotated cone)."""
    disc, ref = case
    info = export(disc, tmp_path / "q.npz", "npz", "S", energy="quadratic")
    P, q, A, b, (z, nn, soc), _ = npz_data(info.path)
    assert P.nnz > 0 and sp.tril(P, -1).nnz == 0 and len(soc) == disc.n_elements
    x, y, value = clarabel_solve(P, q, A, b, [clarabel.ZeroConeT(z), clarabel.NonnegativeConeT(nn)]
                                 + [clarabel.SecondOrderConeT(s) for s in soc])
    assert abs(value - ref.value_S) <= CLARABEL_VALUE * abs(ref.value_S)
    sol = solution_from_answer(disc, answer_from_solution(disc, x, y, read_sidecar(info.path)))
    assert sol.kkt.worst <= CLARABEL_KKT


# ----------------------------------------------------------------------------
# negative controls, the sidecar, refusals
# ----------------------------------------------------------------------------


def test_a_perturbed_answer_fails_the_certificate(case, tmp_path):
    disc, _ = case
    info = export(disc, tmp_path / "p.npz", "npz", "S")
    meta = read_sidecar(info.path)
    P, q, A, b, (z, nn, soc), _ = npz_data(info.path)
    x, y, _ = clarabel_solve(P, q, A, b, [clarabel.ZeroConeT(z), clarabel.NonnegativeConeT(nn)]
                             + [clarabel.SecondOrderConeT(s) for s in soc])
    good = solution_from_answer(disc, answer_from_solution(disc, x, y, meta))
    assert good.kkt.worst <= CLARABEL_KKT
    # one element's stress 1% off
    t0 = meta["variables"]["tau"][0]
    worst_el = int(np.argmax(np.abs(good.sigma).sum(axis=1)))
    x_bad = x.copy()
    x_bad[t0 + worst_el * disc.k:t0 + (worst_el + 1) * disc.k] *= 1.01
    bad = solution_from_answer(disc, answer_from_solution(disc, x_bad, y, meta))
    assert bad.kkt.worst > max(10 * CLARABEL_KKT, SCS_KKT), bad.kkt.as_dict()
    # the rigid body's displacement 1% off (the dual of the force balance)
    y_bad = y.copy()
    y_bad[meta["rows"]["force"][0]] *= 1.01
    bad = solution_from_answer(disc, answer_from_solution(disc, x, y_bad, meta))
    assert bad.kkt.worst > max(10 * CLARABEL_KKT, SCS_KKT) and bad.kkt.penetration + bad.kkt.complementarity > 1e-3
    # the duals' sign flipped: displacements pointing the wrong way
    bad = solution_from_answer(disc, answer_from_solution(disc, x, -y, meta))
    assert bad.kkt.worst > 0.1


def test_sidecar_maps_the_variables_back(case, tmp_path):
    disc, ref = case
    info = export(disc, tmp_path / "p.cbf", "cbf", "S")
    meta = json.loads((tmp_path / "p.cbf.json").read_text())
    assert info.sidecar == tmp_path / "p.cbf.json" and meta == read_sidecar(info.path)
    assert meta["sha256"] == hashlib.sha256(info.path.read_bytes()).hexdigest()
    assert meta["problem_id"] == resolve(disc.problem, "conic", {}).problem_id
    n, k = disc.n_elements, disc.k
    var = meta["variables"]
    assert var["tau"] == [0, n * k] and var["xi"] == [n * k, n * k + n]
    assert var["lam"] == [n * k + n, n * k + n + disc.n_contact] and var["t"][1] == info.n_variables
    assert meta["rows"]["equilibrium"] == [0, disc.n_free] and meta["rows"]["force"] == [disc.n_free, disc.n_free + 1]
    assert meta["mesh"] == {"dim": disc.dim, "n_nodes": disc.mesh.n_nodes, "n_elements": n, "k": k,
                            "n_free_dofs": disc.n_free, "n_contact_nodes": disc.n_contact}
    assert meta["free_dofs"] == disc.free.tolist() and meta["contact_nodes"] == disc.contact_nodes.tolist()
    u = meta["units"]
    assert u["energy"] == pytest.approx(u["force"] * u["displacement"], rel=1e-15)
    assert u["displacement"] == pytest.approx(u["length"] * u["stress"] / disc.material.E, rel=1e-15)
    # the exact answer, pushed through the documented scaling, has the reference's value
    w = np.sqrt(disc.volumes / disc.volumes.mean())
    x = np.zeros(info.n_variables)
    x[var["tau"][0]:var["tau"][1]] = (ref.sigma * w[:, None] / u["stress"]).ravel()
    x[var["xi"][0]:var["xi"][1]] = ref.xi * w / u["stress"]
    x[var["lam"][0]:var["lam"][1]] = ref.contact_force / u["force"]
    energy = ref.value_S - float(disc.psi @ ref.contact_force)
    x[var["t"][0]] = energy / (u["energy"] * meta["scaling"]["energy_cone_constant"])
    prog = read_cbf(info.path)
    assert prog.c @ x == pytest.approx(ref.value_S, rel=1e-12)
    g = prog.A @ x + prog.b
    eq = slice(0, disc.n_free + 1)
    assert np.abs(g[eq]).max() <= 1e-9 * np.abs(prog.A[eq] @ np.abs(x)).max()
    assert "exported (S)" in info.line() and "value(S)" in info.line()


def test_perfect_plasticity_drops_xi(tmp_path):
    """H = 0 on a crossed mesh: no hardening unknowns, and the value still matches."""
    data = cylinder_dict((16, 8), hardening=0.0)
    data["mesh"]["pattern"] = "crossed"
    with pytest.warns(UserWarning, match="perfect plasticity"):
        disc = build(data)
    ref = ep.solve(disc, "conic", progress=False)
    info = export(disc, tmp_path / "h0.npz", "npz", "S")
    meta = read_sidecar(info.path)
    assert meta["variables"]["xi"] is None
    P, q, A, b, (z, nn, soc), _ = npz_data(info.path)
    x, y, value = clarabel_solve(P, q, A, b, [clarabel.ZeroConeT(z), clarabel.NonnegativeConeT(nn)]
                                 + [clarabel.SecondOrderConeT(s) for s in soc])
    assert abs(value - ref.value_S) <= CLARABEL_VALUE * abs(ref.value_S)
    sol = solution_from_answer(disc, answer_from_solution(disc, x, y, meta))
    assert np.all(sol.xi == 0.0) and sol.kkt.worst <= CLARABEL_KKT


def test_refusals(case, tmp_path):
    disc, _ = case
    for kwargs, field in (({"format": "mps"}, "format"), ({"form": "X"}, "form"),
                          ({"format": "cbf", "energy": "quadratic"}, "energy")):
        with pytest.raises(InputError) as err:
            export(disc, tmp_path / "p.out", **kwargs)
        assert err.value.field == field
    with pytest.raises(InputError) as err:
        export(disc, tmp_path / "missing" / "p.cbf")
    assert err.value.field == "path"
    other = build(cylinder_dict((8, 4)))
    info = export(other, tmp_path / "other.npz", "npz")
    with pytest.raises(InputError, match="another problem"):
        answer_from_solution(disc, np.zeros(info.n_variables), np.zeros(info.n_rows), read_sidecar(info.path))


def test_export_command(tmp_path, capsys):
    """`elastoplast export`: the file and its map back written, the one-line summary printed;
    a CBF with the energy as P (CBF has no quadratic objective) refused naming the flag."""
    from elastoplast.cli.main import main
    from test_cli import small_cylinder, write_toml

    problem = write_toml(tmp_path / "p.toml", small_cylinder())
    out = tmp_path / "p.cbf"
    assert main(["export", str(problem), "--out", str(out), "--quiet"]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("exported (S)") and out.is_file() and (tmp_path / "p.cbf.json").is_file()
    assert read_cbf(out).c.size == read_sidecar(out)["n_variables"]
    code = main(["export", str(problem), "--energy", "quadratic", "--out", str(tmp_path / "q.cbf"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: --energy:"), err


# ----------------------------------------------------------------------------
# the output file: refused before any work, written whole (the adversarial pass's inputs)
# ----------------------------------------------------------------------------


def run_export(capsys, *argv):
    """``elastoplast export ARGV --quiet``: the exit code and the last stderr line."""
    from elastoplast.cli.main import main

    code = main(["export", *map(str, argv), "--quiet"])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    return code, (lines[-1] if lines else ""), captured.out


@pytest.fixture
def victim(tmp_path):
    from test_cli import small_cylinder, write_toml

    return write_toml(tmp_path / "victim.toml", small_cylinder())


@pytest.fixture(scope="module")
def tiny():
    return build(cylinder_dict((8, 4)))


def folder_listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_out_never_overwrites_the_problem_or_a_foreign_file(victim, tmp_path, capsys):
    original = victim.read_bytes()
    code, err, _ = run_export(capsys, victim, "--out", victim)
    assert code == 2 and err.startswith("error: --out:") and "problem's own file" in err
    small = tmp_path / "small2d.toml"
    small.write_bytes(original)
    code, err, _ = run_export(capsys, small, "--out", f"{small}/")
    assert code == 2 and err.startswith("error: --out:") and "names a folder" in err
    good = tmp_path / "good.npz"
    good.write_bytes(b"PK not mine")
    code, err, _ = run_export(capsys, victim, "--out", good)
    assert code == 2 and err.startswith("error: --format:") and "npz" in err, err
    code, err, _ = run_export(capsys, victim, "--out", good, "--format", "npz")
    assert code == 2 and err.startswith("error: --out:") and "not an earlier export" in err, err
    code, err, _ = run_export(capsys, victim, "--out", tmp_path / "p.cbf", "--format", "npz")
    assert code == 2 and err.startswith("error: --format:")
    code, err, _ = run_export(capsys, victim, "--out", "ex/")
    assert code == 2 and err.startswith("error: --out:")
    assert victim.read_bytes() == original and small.read_bytes() == original and good.read_bytes() == b"PK not mine"
    assert not (tmp_path / "ex").exists() and not (tmp_path / "ex.json").exists()
    assert folder_listing(tmp_path) == ["good.npz", "small2d.toml", "victim.toml"]


def test_out_never_overwrites_the_mesh_file(tmp_path, capsys):
    from conftest import PROBLEMS

    for name in ("punch_2d_gmsh.toml", "punch_2d.msh"):
        (tmp_path / name).write_bytes((PROBLEMS / name).read_bytes())
    mesh = (tmp_path / "punch_2d.msh").read_bytes()
    code, err, _ = run_export(capsys, tmp_path / "punch_2d_gmsh.toml", "--out", tmp_path / "punch_2d.msh")
    assert code == 2 and err.startswith("error: --out:") and "problem's own file" in err
    assert (tmp_path / "punch_2d.msh").read_bytes() == mesh


def test_an_earlier_export_is_replaced_and_nothing_else(victim, tmp_path, capsys):
    out = tmp_path / "p.cbf"
    for _ in range(2):
        code, _, printed = run_export(capsys, victim, "--out", out)
        assert code == 0 and printed.startswith("exported (S)")
    assert read_sidecar(out)["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()
    out.write_bytes(out.read_bytes() + b"# edited by hand\n")  # no longer the export its sidecar describes
    code, err, _ = run_export(capsys, victim, "--out", out)
    assert code == 2 and "not an earlier export" in err and out.read_bytes().endswith(b"# edited by hand\n")
    stale = tmp_path / "q.cbf"  # a sidecar left alone by an earlier export: replaced
    code, _, _ = run_export(capsys, victim, "--out", stale)
    stale.unlink()
    assert code == 0 and run_export(capsys, victim, "--out", stale)[0] == 0 and stale.is_file()
    (tmp_path / "r.cbf.json").write_text("{}")  # a foreign file in the sidecar's place
    code, err, _ = run_export(capsys, victim, "--out", tmp_path / "r.cbf")
    assert code == 2 and "r.cbf.json exists" in err and not (tmp_path / "r.cbf").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("out", ["sub", ".", "/", "", "loop", "a" * 300 + ".cbf", "/proc/x.cbf", "/sys/x.cbf",
                                 "/dev/full", "sd/p.cbf", "nosuch/p.cbf"])
def test_bad_out_paths_are_bad_input(victim, tmp_path, capsys, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sd" / "p.cbf.json").mkdir(parents=True)
    (tmp_path / "loop").symlink_to("loop")
    if out.startswith(("/proc", "/sys", "/dev")) and not Path(out).parent.is_dir():
        pytest.skip(f"no {Path(out).parent}")
    before = folder_listing(tmp_path)
    code, err, _ = run_export(capsys, victim, "--out", out)
    assert code == 2 and err.startswith("error: --out:"), err
    assert folder_listing(tmp_path) == before and folder_listing(tmp_path / "sd") == ["p.cbf.json"]


def test_odd_file_names_make_valid_files(victim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, shown_as in (("été.cbf", "\\u00e9t\\u00e9.cbf.json"), ("nl\nVER\n4\n.cbf", "nl\\nVER\\n4\\n.cbf.json")):
        code, _, printed = run_export(capsys, victim, "--out", name)
        assert code == 0 and printed.count("\n") == 1, printed
        text = (tmp_path / name).read_text(encoding="ascii")
        assert text.splitlines()[1] == f"# variables and rows: see {shown_as}" and text.endswith("\n")
        prog = read_cbf(tmp_path / name)
        assert prog.version == 3 and prog.c.size == read_sidecar(tmp_path / name)["n_variables"]


def test_cbf_comments_are_one_ascii_line_each(tiny):
    from elastoplast.io.cbf import cbf_text, escape_comment

    prog = stress_form(tiny).program
    assert cbf_text(prog).endswith("\n") and not cbf_text(prog).endswith("\n\n")
    for bad in ("nl\nVER\n4", "cr\r", "\u2028", "é"):
        prog.comments = [bad]
        with pytest.raises(ValueError, match="CBF comment"):
            cbf_text(prog)
        prog.comments = [escape_comment(bad)]
        assert cbf_text(prog).splitlines()[0].startswith("# ") and len(cbf_text(prog).splitlines()[0]) < 40
    assert escape_comment("a\\b\n\u00e9\U0001f600") == "a\\\\b\\n\\u00e9\\U0001f600"


@pytest.mark.parametrize("path, field", [(None, "path"), (123, "path"), (b"x", "path"), ("a\0b.cbf", "path"),
                                         (".", "path"), ("", "path"), ("q.npz", "format")])
def test_python_export_paths(tiny, tmp_path, monkeypatch, path, field):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError) as err:
        export(tiny, path)
    assert err.value.field == field and folder_listing(tmp_path) == []


@pytest.mark.parametrize("failing", ["data", "replace"])
def test_a_failed_write_leaves_no_half_pair(tiny, tmp_path, monkeypatch, failing):
    import errno
    import os

    from elastoplast.io import export_files

    if failing == "data":
        def broken(fd, data):
            os.close(fd)
            raise OSError(errno.ENOSPC, "No space left on device")
        monkeypatch.setattr(export_files, "_write_all", broken)
    else:
        real = os.replace

        def broken(src, dst):
            if str(dst).endswith(".json"):
                raise OSError(errno.EISDIR, "Is a directory")
            return real(src, dst)
        monkeypatch.setattr(export_files.os, "replace", broken)
    with pytest.raises(InputError) as err:
        export(tiny, tmp_path / "p.cbf")
    assert err.value.field == "path" and "cannot write" in err.value.message
    assert folder_listing(tmp_path) == []


def test_readers_refuse_what_is_no_export(tiny, tmp_path):
    with pytest.raises(InputError) as err:
        read_sidecar(tmp_path / "missing.cbf")
    assert err.value.field == "path"
    with pytest.raises(InputError) as err:
        read_cbf(tmp_path / "missing.cbf")
    assert err.value.field == "cbf"
    (tmp_path / "bin.cbf").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="not ASCII") as err:
        read_cbf(tmp_path / "bin.cbf")
    assert err.value.field == "cbf"
    info = export(tiny, tmp_path / "p.cbf")
    with pytest.raises(InputError, match="not an npz") as err:
        load_npz(info.path)
    assert err.value.field == "path"
    (tmp_path / "x.json").write_text("[1, 2]")
    with pytest.raises(InputError) as err:
        read_sidecar(tmp_path / "x.json")
    assert err.value.field == "path"
    meta = read_sidecar(info.path)
    for x, y, field in ((np.zeros(3), np.zeros(info.n_rows), "x"), (np.zeros(info.n_variables), np.zeros(3), "y"),
                        (np.zeros((2, info.n_variables)), np.zeros(info.n_rows), "x")):
        with pytest.raises(InputError) as err:
            answer_from_solution(tiny, x, y, meta)
        assert err.value.field == field
    with pytest.raises(InputError) as err:
        answer_from_solution(tiny, np.zeros(info.n_variables), np.zeros(info.n_rows), {"form": "S"})
    assert err.value.field == "meta"


def test_a_force_above_the_limit_load_gets_a_note(tmp_path, capsys):
    from test_cli import small_cylinder, write_toml

    data = small_cylinder()
    data["material"]["hardening"] = 1.0
    data["load"]["force"] = 1e7
    problem = write_toml(tmp_path / "heavy.toml", data)
    from elastoplast.cli.main import main

    assert main(["export", str(problem), "--out", str(tmp_path / "h.cbf"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "note: the force 1e+07 is far above the limit load" in err, err
    problem = write_toml(tmp_path / "light.toml", small_cylinder())
    assert main(["export", str(problem), "--out", str(tmp_path / "l.cbf"), "--quiet"]) == 0
    assert "note:" not in capsys.readouterr().err
