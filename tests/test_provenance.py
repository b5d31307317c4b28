"""The stamp of a benchmark record describes the code as the script started."""

from __future__ import annotations

import elastoplast.io.provenance as prov


def test_stamp_keeps_the_source_state_of_the_start(monkeypatch):
    states = iter([("a" * 40, False), ("a" * 40, True)])  # clean at the start, dirty once plots are written
    monkeypatch.setattr(prov, "source_commit", lambda: next(states))
    monkeypatch.setattr(prov, "_SOURCE_AT_START", None)
    prov.record_parser("doc")
    s = prov.stamp("python x.py")
    assert (s["commit"], s["dirty"]) == ("a" * 40, False)
    assert "uncommitted" not in prov.stamp_line(s)


def test_stamp_without_a_parser_reads_the_source_now(monkeypatch):
    monkeypatch.setattr(prov, "source_commit", lambda: ("b" * 40, True))
    monkeypatch.setattr(prov, "_SOURCE_AT_START", None)
    s = prov.stamp()
    assert (s["commit"], s["dirty"]) == ("b" * 40, True)
    assert "(uncommitted changes)" in prov.stamp_line(s)
