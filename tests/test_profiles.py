"""Performance profiles and shifted geometric means (elastoplast/studies/profiles.py)
against values computed by hand, and ``elastoplast compare SUITE_DIR`` on a tiny suite."""

from __future__ import annotations

import json
import math

import pytest

from elastoplast.cli.main import main
from elastoplast.plots.figures import plot_profile
from elastoplast.studies.profiles import (
    fraction_solved,
    performance_profile,
    performance_ratios,
    profile_taus,
    shifted_geometric_mean,
)
from elastoplast.studies.suite import is_solved, is_suite_dir, profile_markdown, profile_record

#: two methods, three instances, one failure (A on p3)
TIMES = {"A": {"p1": 1.0, "p2": 4.0, "p3": None},
         "B": {"p1": 2.0, "p2": 2.0, "p3": 3.0}}


def test_ratios_by_hand():
    # best times: p1 1 (A), p2 2 (B), p3 3 (B, the only one to solve it)
    # A: 1/1 = 1, 4/2 = 2, failed = inf;  B: 2/1 = 2, 2/2 = 1, 3/3 = 1
    r = performance_ratios(TIMES)
    assert r["A"] == {"p1": 1.0, "p2": 2.0, "p3": math.inf}
    assert r["B"] == {"p1": 2.0, "p2": 1.0, "p3": 1.0}


def test_profile_by_hand():
    # rho_A(tau) = #{ratios of A <= tau} / 3: tau = 1 -> {p1} = 1/3; 1.5 -> 1/3; 2 -> {p1, p2} = 2/3; 4 -> 2/3
    # (p3 never: A failed there); rho_B: tau = 1 -> {p2, p3} = 2/3; 1.5 -> 2/3; 2 -> all three = 1; 4 -> 1
    prof = performance_profile(TIMES, [1.0, 1.5, 2.0, 4.0])
    assert prof["A"] == pytest.approx([1 / 3, 1 / 3, 2 / 3, 2 / 3])
    assert prof["B"] == pytest.approx([2 / 3, 2 / 3, 1.0, 1.0])
    # the steps are at 1 and at every finite ratio (here 2), then 2 x the largest
    assert profile_taus(TIMES) == [1.0, 2.0, 4.0]
    assert fraction_solved(TIMES) == pytest.approx({"A": 2 / 3, "B": 1.0})


def test_shifted_geometric_mean_by_hand():
    # shift 1, the failure counted at 10 s:
    # A: ((1+1)(4+1)(10+1))^(1/3) - 1 = 110^(1/3) - 1;  B: ((2+1)(2+1)(3+1))^(1/3) - 1 = 36^(1/3) - 1
    sgm = shifted_geometric_mean(TIMES, 1.0, failure_time=10.0)
    assert sgm["A"] == pytest.approx(110 ** (1 / 3) - 1)
    assert sgm["B"] == pytest.approx(36 ** (1 / 3) - 1)
    # shift 0 is the plain geometric mean: A (1 * 4 * 10)^(1/3)
    assert shifted_geometric_mean(TIMES, 0.0, failure_time=10.0)["A"] == pytest.approx(40 ** (1 / 3))
    with pytest.raises(ValueError):
        shifted_geometric_mean(TIMES, failure_time=math.inf)


def test_failures_ties_and_unsolved_instances():
    # inf and a missing instance are failures like None; an instance nobody solves stays in the
    # denominator (here 4 instances); a tie at the best time counts for both methods
    times = {"A": {"p1": 1.0, "p2": math.inf, "p3": 5.0, "p4": None},
             "B": {"p1": 1.0, "p2": 3.0, "p4": None}}
    prof = performance_profile(times, [1.0, 10.0])
    # A: p1 (tie, ratio 1), p3 (only A solved it, ratio 1) -> 2/4 at tau 1; B: p1, p2 -> 2/4
    assert prof == {"A": [0.5, 0.5], "B": [0.5, 0.5]}
    assert fraction_solved(times) == {"A": 0.5, "B": 0.5}
    # B failed on p3 (missing) and p4: (2 * 4 * 11 * 11)^(1/4) - 1
    assert shifted_geometric_mean(times, failure_time=10.0)["B"] == pytest.approx((2 * 4 * 11 * 11) ** 0.25 - 1)


def _run(method, instance, status, t, worst=1e-9):
    return {"method": method, "instance": instance, "status": status, "time_s": t, "kkt_worst": worst,
            "dim": 2, "n_elements": 100, "message": "m"}


def test_profile_record_counts_only_certified_answers():
    runs = [_run("A", "p1", "converged", 1.0), _run("A", "p2", "converged", 4.0),
            _run("A", "p3", "max_iterations", 7.0, 1e-3),
            _run("B", "p1", "converged", 2.0), _run("B", "p2", "converged", 2.0), _run("B", "p3", "converged", 3.0),
            _run("B", "p4", "converged", 1.0, worst=1e-4)]  # converged, but not at the suite's tolerance
    assert not is_solved(runs[-1], 1e-6) and is_solved(runs[0], 1e-6)
    rec = profile_record(runs[:-1], tol=1e-6, time_limit=10.0)
    assert rec["times"] == TIMES and rec["failure_time_s"] == 10.0
    assert rec["shifted_geometric_mean_s"]["A"] == pytest.approx(110 ** (1 / 3) - 1)
    assert rec["profile_at"]["2.0"] == pytest.approx({"A": 2 / 3, "B": 1.0})
    assert rec["failures"]["A"][0]["status"] == "max_iterations"
    text = profile_markdown(rec)
    assert "✗ max_iterations" in text and "| B | 3/3 (100%) |" in text
    # without a time limit a failure counts twice the longest solved time (4 s here)
    assert profile_record(runs[:-1], tol=1e-6, time_limit=None)["failure_time_s"] == 8.0


def test_plot_profile_writes_a_png(tmp_path):
    taus = profile_taus(TIMES)
    plot_profile(performance_profile(TIMES, taus), tmp_path / "p.png", taus=taus)
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


SMALL = """
[mesh]
generator = "rectangle"
size = [40.0, 20.0]
divisions = [{nx}, 8]
grading = 2.0
contact_radius = 4.0
[material]
E = 200000.0
nu = 0.3
yield_stress = 1200.0
hardening = 20000.0
[obstacle]
shape = "cylinder"
radius = 40.0
[load]
force = 4315.0
"""


def test_compare_on_a_suite_folder(tmp_path, capsys):
    suite = tmp_path / "suite"
    suite.mkdir()
    for nx in (16, 20):
        (suite / f"c{nx}.toml").write_text(SMALL.format(nx=nx))
    assert is_suite_dir(suite)
    out = tmp_path / "prof"
    code = main(["compare", str(suite), "--method", "newton", "--method", "uzawa", "--tol", "1e-6",
                 "--max-iter", "10", "--time-limit", "60", "--out", str(out), "--quiet"])
    # uzawa stops after 10 iterations (it needs about 60; newton about 6) (--max-iter applies to every method that has it): not solved
    assert code == 1
    data = json.loads((out / "profile.json").read_text())
    assert data["statuses"]["uzawa"] == {"c16": "max_iterations", "c20": "max_iterations"}
    assert data["fraction_solved"] == {"newton": 1.0, "uzawa": 0.0}
    assert data["profile"]["newton"][0] == 1.0 and data["failure_time_s"] == 60.0
    assert data["instances"]["c16"] == {"dim": 2, "n_elements": 256}
    assert (out / "profile.png").exists() and "| newton | 2/2 (100%)" in (out / "profile.md").read_text()
    assert "| c20 | 2 | 320 |" in capsys.readouterr().out
    # a store folder (index.sqlite) is not a suite; a suite needs --out
    assert main(["compare", str(suite), "--method", "newton"]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["compare", str(suite), "--method", "nope", "--out", str(tmp_path / "x")]) == 2
    assert "--method" in capsys.readouterr().err
    (suite / "index.sqlite").write_bytes(b"")
    assert not is_suite_dir(suite)
