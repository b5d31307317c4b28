"""The choice of the lower bound (issue 17): the global program or the local field.

``LowerBoundOptions.kind`` ("auto", "local", "global") picks it
(:func:`~elastoplast.bounds.lower.lower_bound_kind`): "auto" keeps the global program for
H = 0 (the only lower bound there) and on small meshes, the local bound above; the global
program's size and memory refusals apply to it alone. Every lower bound goes through one
entry point (:func:`~elastoplast.bounds.bracket.lower_bound`); the U bracket with the local
bound solves at F -/+ delta first. Only theorems are asserted between the two kinds: both
brackets contain the true energy and U, so they overlap; neither bound is asserted below
the other.
"""

from __future__ import annotations

import json
import math

import pytest

import elastoplast as ep
import elastoplast.bounds.lower as lower_module
from elastoplast.adapt.budget import lower_bound_budget
from elastoplast.adapt.records import AdaptOptions
from elastoplast.references.solves import LOCAL_SOLVE_TOL, local_solution, solve_at
from elastoplast.references.certified import certified_bounds
from elastoplast.bounds.bracket import check_lower_bound_fits, local_descent, lower_bound
from elastoplast.bounds.local.construction import DESCENT_STEPS
from elastoplast.bounds.lower import AUTO_GLOBAL_MAX_ELEMENTS, LowerBoundOptions, lower_bound_kind
from elastoplast.cli.main import main
from elastoplast.errors import InputError
from elastoplast.limits import MEMORY_ENV

from conftest import cylinder_dict
from test_cli import write_toml


@pytest.fixture(scope="module")
def cylinder():
    disc = ep.discretize(ep.problem_from_dict(cylinder_dict(divisions=(24, 12))))  # 576 triangles, plastic
    return disc, ep.solve(disc, "newton")


def perfectly_plastic():
    return ep.discretize(ep.problem_from_dict(cylinder_dict(divisions=(10, 5), hardening=0.0)))


# ---------------------------------------------------------------------------
# the choice
# ---------------------------------------------------------------------------


def test_auto_takes_the_global_program_on_small_meshes_and_the_local_bound_above(cylinder, monkeypatch):
    disc, _ = cylinder
    assert disc.n_elements <= AUTO_GLOBAL_MAX_ELEMENTS[2]
    assert lower_bound_kind(disc) == lower_bound_kind(disc, LowerBoundOptions(kind="auto")) == "global"
    monkeypatch.setitem(AUTO_GLOBAL_MAX_ELEMENTS, 2, disc.n_elements - 1)  # the same mesh is now "large"
    assert lower_bound_kind(disc) == "local"
    assert lower_bound_kind(disc, {"kind": "global"}) == "global"  # explicit kinds are honoured
    monkeypatch.setitem(AUTO_GLOBAL_MAX_ELEMENTS, 2, disc.n_elements)
    assert lower_bound_kind(disc) == "global"
    assert lower_bound_kind(disc, LowerBoundOptions(kind="local")) == "local"


@pytest.mark.filterwarnings("ignore:material.hardening = 0")
def test_without_hardening_only_the_global_program(monkeypatch):
    disc = perfectly_plastic()
    monkeypatch.setitem(AUTO_GLOBAL_MAX_ELEMENTS, 2, 1)
    assert lower_bound_kind(disc) == "global"  # whatever the size
    with pytest.raises(InputError) as info:
        lower_bound_kind(disc, LowerBoundOptions(kind="local"))
    assert info.value.field == "kind" and "hardening" in info.value.message


@pytest.mark.parametrize("bad", ["Local", "", "both", 1, None])
def test_a_bad_kind_is_refused_naming_it(bad):
    with pytest.raises(InputError) as info:
        LowerBoundOptions(kind=bad)
    assert info.value.field == "kind" and "auto" in info.value.message and "local" in info.value.message
    with pytest.raises(InputError) as info:
        LowerBoundOptions.of({"kind": bad}, "lower_options")
    assert info.value.field == "lower_options.kind"
    with pytest.raises(InputError) as info:
        AdaptOptions(lower=bad)
    assert info.value.field == "lower"


def test_the_size_and_memory_refusals_are_the_global_programs_only(cylinder, monkeypatch):
    disc, sol = cylinder
    for table in (lower_module.LOWER_BOUND_MAX_ELEMENTS, lower_module.CLARABEL_MAX_ELEMENTS):
        monkeypatch.setitem(table, 2, disc.n_elements - 1)
    with pytest.raises(InputError) as info:
        check_lower_bound_fits(disc, LowerBoundOptions(kind="global"))
    assert info.value.field == "mesh" and "equilibrium-element" in info.value.message
    with pytest.raises(InputError):
        lower_bound(disc, sol, {"kind": "global"})
    assert check_lower_bound_fits(disc, LowerBoundOptions(kind="local")) == "local"
    monkeypatch.setitem(AUTO_GLOBAL_MAX_ELEMENTS, 2, 10)
    assert check_lower_bound_fits(disc) == "local"  # auto on a "large" mesh: no 25k-style refusal
    # the local bound has its own memory estimate
    monkeypatch.setenv(MEMORY_ENV, "1M")
    with pytest.raises(InputError) as info:
        check_lower_bound_fits(disc, LowerBoundOptions(kind="local"))
    assert info.value.field == "mesh" and "local lower bound" in info.value.message


def test_adaptive_budget_follows_the_lower_bound_used(monkeypatch):
    monkeypatch.setenv(MEMORY_ENV, "1T")
    glob = lower_module.LOWER_BOUND_MAX_ELEMENTS[3]
    assert lower_bound_budget(3, AdaptOptions(lower="global")) == ("the lower bound's size limit", glob)
    for kind in ("auto", "local"):  # the 25,000-tetrahedra limit is gone; the element budget remains
        name, largest = lower_bound_budget(3, AdaptOptions(lower=kind))
        assert largest > glob and "memory" in name or name == "max_elements", (kind, name, largest)
    assert lower_bound_budget(3, AdaptOptions(lower="local"), hardening=False)[1] == glob  # H = 0: the program
    assert lower_bound_budget(3, AdaptOptions(lower="local", lower_max_elements=500))[1] == 500
    monkeypatch.setenv(MEMORY_ENV, "4G")  # the largest mesh the sweeps alone fit (the descent is dropped there)
    per = lower_module.LOCAL_SWEEPS_BYTES_PER_ELEMENT[3]
    assert lower_bound_budget(3, AdaptOptions(lower="local")) == ("the memory available to the lower bound",
                                                                   4 * 2**30 // per)


def test_local_bound_drops_its_descent_where_only_the_sweeps_fit(cylinder, monkeypatch):
    """Memory between the sweeps' estimate and the descent's (lower.LOCAL_SWEEPS_BYTES_PER_ELEMENT,
    LOCAL_BOUND_BYTES_PER_ELEMENT): the local bound runs its sweeps alone, says so in a warning,
    and is still certified; its message names no descent step. Below the sweeps' estimate the
    bounds are refused before any work; with room the default descent runs."""
    disc, sol = cylinder
    n = disc.n_elements
    sweeps = lower_module.lower_bound_bytes(2, n, "local", descent=False)
    full = lower_module.lower_bound_bytes(2, n, "local")
    assert sweeps < full
    local = LowerBoundOptions(kind="local")
    monkeypatch.setenv(MEMORY_ENV, str((sweeps + full) // 2))
    with pytest.warns(UserWarning, match="sweeps alone run"):
        assert local_descent(disc, local) == 0
    assert check_lower_bound_fits(disc, local) == "local"
    with pytest.warns(UserWarning, match="sweeps alone run"):
        lb = lower_bound(disc, local_solution(disc, sol), local)
    assert lb.certified and "descent step" not in lb.message, lb.message
    monkeypatch.setenv(MEMORY_ENV, str(sweeps // 2))
    with pytest.raises(InputError) as info:
        check_lower_bound_fits(disc, local)
    assert info.value.field == "mesh" and "without its descent" in info.value.message
    monkeypatch.setenv(MEMORY_ENV, str(2 * full))
    assert local_descent(disc, local) == DESCENT_STEPS[2]
    assert local_descent(disc, LowerBoundOptions(kind="local", descent=7)) == 7


# ---------------------------------------------------------------------------
# the entry point and the bracket
# ---------------------------------------------------------------------------


def test_local_bound_needs_a_solution(cylinder):
    disc, _ = cylinder
    with pytest.raises(InputError) as info:
        lower_bound(disc, None, {"kind": "local"})
    assert info.value.field == "solution"
    with pytest.raises(InputError) as info:
        lower_bound(disc, "x", {"kind": "local"})
    assert info.value.field == "solution"


def test_warm_started_solve_at_another_force(cylinder):
    disc, sol = cylinder
    F = 0.9 * disc.force
    warm = solve_at(disc, F, "newton", sol, LOCAL_SOLVE_TOL)
    cold = ep.solve(disc.with_force(F), "newton", tol=LOCAL_SOLVE_TOL)
    assert warm.converged and warm.kkt.worst <= LOCAL_SOLVE_TOL and warm.iterations <= cold.iterations
    assert warm.U == pytest.approx(cold.U, rel=1e-8)


def test_the_local_bracket_holds_and_overlaps_the_global_one(cylinder, monkeypatch):
    import elastoplast.bounds.local.construction as local_module

    disc, sol = cylinder
    seen, uppers = [], []
    build = local_module.local_lower_bound

    def spy(d, s, *args, upper=None, **kwargs):
        lb = build(d, s, *args, upper=upper, **kwargs)
        uppers.append((d.force, upper, lb.lower))
        return lb

    monkeypatch.setattr(local_module, "local_lower_bound", spy)
    local = certified_bounds(disc, sol, "newton", lower_options={"kind": "local"},
                             progress=lambda fraction, what: seen.append(fraction))
    # every local bound, at F and at F -/+ delta, is given an upper bound of its own force (for its
    # descent's gap stop), and each is above that lower bound (both are bounds of the same problem)
    assert len(uppers) == 3 and len({f for f, _, _ in uppers}) == 3
    assert all(up is not None and math.isfinite(up) and lo <= up for _, up, lo in uppers)
    glob = certified_bounds(disc, sol, "newton", lower_options={"kind": "global"})
    assert local.lower.solver == "local" and glob.lower.solver != "local"
    assert local.as_dict()["lower_bound_kind"] == "local" and glob.as_dict()["lower_bound"]["kind"] == "global"
    for rep in (local, glob):
        b = rep.bounds
        assert rep.certified, rep.lower.message
        assert b.energy_lower <= b.energy_upper
        assert rep.U_lower <= sol.U <= rep.U_upper  # measured (wide margins on this mesh), not a theorem
        assert math.isfinite(b.stress_error_bound)
    # both brackets contain the true energy and the true U: they overlap (the theorem; which
    # lower bound is higher is not one)
    assert max(local.bounds.energy_lower, glob.bounds.energy_lower) <= min(local.bounds.energy_upper,
                                                                            glob.bounds.energy_upper)
    assert max(local.U_lower, glob.U_lower) <= min(local.U_upper, glob.U_upper)
    assert local.bounds.energy_upper == glob.bounds.energy_upper  # the same upper side
    assert seen and seen == sorted(seen) and 0.0 <= seen[0] and seen[-1] == pytest.approx(1.0)


# ---------------------------------------------------------------------------
# the command line
# ---------------------------------------------------------------------------


@pytest.mark.filterwarnings("ignore:material.hardening = 0")
def test_bounds_and_adapt_take_the_lower_option(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", cylinder_dict(divisions=(10, 5)))
    code = main(["bounds", str(problem), "--method", "newton", "--lower", "local", "--quiet",
                 "--out", str(tmp_path / "b")])
    out = capsys.readouterr().out
    assert code == 0 and "lower bound: local field" in out and "certified" in out, out
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["lower_bound_kind"] == "local" and summary["bounds_certified"]
    assert summary["U_lower"] <= summary["U_upper"]

    code = main(["adapt", str(problem), "--rtol", "0.5", "--bracket", "never", "--no-uniform", "--lower", "local",
                 "--quiet", "--out", str(tmp_path / "a")])
    out = capsys.readouterr().out
    assert code == 0 and "(local lower bound)" in out, out
    steps = json.loads((tmp_path / "a" / "adapt.json").read_text())["adaptive"]
    assert steps and all(s["lower"] == "local" for s in steps)
    assert "lower bound |" in (tmp_path / "a" / "adapt.md").read_text()

    for command in ("bounds", "adapt"):
        code = main([command, str(problem), "--lower", "fast", "--quiet", "--out", str(tmp_path / "x")])
        assert code == 2 and "--lower" in capsys.readouterr().err
    plastic = write_toml(tmp_path / "h0.toml", cylinder_dict(divisions=(10, 5), hardening=0.0))
    code = main(["bounds", str(plastic), "--lower", "local", "--quiet", "--out", str(tmp_path / "y")])
    err = capsys.readouterr().err
    assert code == 2 and "error: --lower:" in err and "hardening" in err, err
    assert not (tmp_path / "y").exists()


def test_help_documents_the_choice(capsys):
    from elastoplast.cli.main import build_parser

    parser = build_parser()
    for command in ("bounds", "adapt"):
        with pytest.raises(SystemExit):
            parser.parse_args([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "--lower {auto,local,global}" in text and "'auto' (default)" in text
        assert f"{AUTO_GLOBAL_MAX_ELEMENTS[3]:,} tetrahedra" in text


def test_the_descent_option_reaches_the_local_bound(tmp_path, capsys):
    """``--descent`` sets the local bound's steps over all rings (bounds and adapt); a bad
    count is refused naming the flag. The count taken is read back from the bound's message
    (the descent may stop earlier, never later)."""
    problem = write_toml(tmp_path / "p.toml", cylinder_dict(divisions=(10, 5)))
    seen = {}
    for steps in (0, 3):
        out = tmp_path / f"b{steps}"
        code = main(["bounds", str(problem), "--method", "newton", "--lower", "local", "--descent", str(steps),
                     "--no-bracket", "--quiet", "--out", str(out)])
        capsys.readouterr()
        summary = json.loads((out / "summary.json").read_text())
        assert code == 0 and summary["bounds_certified"]
        seen[steps] = summary["lower_bound"]
    assert "descent step" not in seen[0]["message"]
    taken = int(seen[3]["message"].split(" descent step")[0].rsplit(" ", 1)[1])
    assert 1 <= taken <= 3
    for command in ("bounds", "adapt"):
        for bad in ("x", "-1"):
            code = main([command, str(problem), "--descent", bad, "--quiet", "--out", str(tmp_path / command)])
            err = capsys.readouterr().err
            assert code == 2 and "--descent" in err and bad in err and "Traceback" not in err, err
    options = LowerBoundOptions(descent=0)
    assert options.descent == 0 and LowerBoundOptions().descent is None
