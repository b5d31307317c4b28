"""The stamp of a record (elastoplast.io.provenance) and the benchmark harness that
writes records (benchmarks/harness.py): the stamp describes the code as the script
started, and a child process reports its own peak memory."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

import elastoplast.io.provenance as prov

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import harness  # noqa: E402

MB = 2**20

#: a benchmark script in miniature: its child entry allocates ``spec`` MB
CHILD_SCRIPT = """
import sys
sys.path.insert(0, {benchmarks!r})
import numpy as np
from harness import peak_memory, run_record

def child(spec):
    if spec == "fail":
        raise ValueError("no such case")
    block = np.ones(spec * 2**20 // 8)
    return {{"peak": peak_memory(), "sum": block.sum()}}

sys.exit(run_record("doc", "tiny", {topic!r}, "T", "child test", lambda mode, out: {{}}, str, child=child))
"""


def test_stamp_keeps_the_source_state_of_the_start(monkeypatch):
    states = iter([("a" * 40, False), ("a" * 40, True)])  # clean at the start, dirty once plots are written
    monkeypatch.setattr(prov, "source_commit", lambda: next(states))
    monkeypatch.setattr(prov, "_SOURCE_AT_START", None)
    prov.freeze_source()
    s = prov.stamp("python x.py")
    assert (s["commit"], s["dirty"]) == ("a" * 40, False)
    assert "uncommitted" not in prov.stamp_line(s)


def test_stamp_without_a_start_reads_the_source_now(monkeypatch):
    monkeypatch.setattr(prov, "source_commit", lambda: ("b" * 40, True))
    monkeypatch.setattr(prov, "_SOURCE_AT_START", None)
    s = prov.stamp()
    assert (s["commit"], s["dirty"]) == ("b" * 40, True)
    assert "(uncommitted changes)" in prov.stamp_line(s)


def test_run_record_writes_a_stamped_record_and_report_renders_it_again(monkeypatch, tmp_path):
    tree = {"dirty": False}
    monkeypatch.setattr(prov, "source_commit", lambda: ("c" * 40, tree["dirty"]))
    monkeypatch.setattr(prov, "_SOURCE_AT_START", None)
    seen = {}

    def run(mode, out, scale):
        seen.update(mode=mode, out=out, scale=scale)
        tree["dirty"] = True  # the script writes into the tracked tree as it runs
        return {"value": np.float64(1.5) * scale}

    def render(results):
        return f"value {results['value']}"

    def main(*argv):
        return harness.run_record("doc", "tiny", tmp_path, "Title", "test", run, render, argv=list(argv), study="s",
                                  options={"--scale": {"type": float, "default": 1.0}})

    assert main("--quick", "--scale", "2") == 0
    assert seen == {"mode": "quick", "out": tmp_path / "quick", "scale": 2.0}
    json_path, md_path = harness.record_paths(tmp_path / "quick", "s")
    record = json.loads(json_path.read_text())
    assert record["value"] == 3.0 and "total_time_s" in record
    assert (record["stamp"]["commit"], record["stamp"]["dirty"]) == ("c" * 40, False)
    report = md_path.read_text()
    assert report == f"# Title\n\n{prov.stamp_line(record['stamp'])}\n\nvalue 3.0\n"
    recorded = json_path.read_bytes()
    md_path.unlink()
    seen.clear()
    assert main("--quick", "--report") == 0
    assert not seen and json_path.read_bytes() == recorded and md_path.read_text() == report


def test_a_record_without_a_stamp_says_so():
    assert harness.report_text("T", {"x": 1}, "body\n") == f"# T\n\n{harness.UNSTAMPED_LINE}\n\nbody\n"


def test_script_command_names_the_script_as_the_readmes_do(monkeypatch):
    script = Path(harness.__file__).resolve().parent / "bounds" / "run.py"
    monkeypatch.setattr(sys, "argv", [str(script), "--quick"])
    assert harness.script_command() == "python benchmarks/bounds/run.py --quick"


def test_a_child_process_reports_its_own_peak_memory(tmp_path):
    script = tmp_path / "study.py"
    script.write_text(CHILD_SCRIPT.format(benchmarks=str(Path(harness.__file__).parent), topic=str(tmp_path)))
    held = np.ones(384 * MB // 8)  # this process's peak is above 384 MB, and Linux hands ru_maxrss on to children
    assert harness.peak_memory() >= held.nbytes
    row = harness.run_child(script, 32)
    assert row["sum"] == 32 * MB // 8
    assert 32 * MB <= row["peak"] < 300 * MB  # the child's 32 MB and its imports, not this process's peak
    assert harness.run_child(script, "fail") == {"error": "ValueError: no such case"}
    with pytest.raises(SystemExit, match="no such case"):
        harness.run_child(script, "fail", check=True)
