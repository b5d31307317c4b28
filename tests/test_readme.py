"""The README's set-up commands and its Python blocks are what they claim."""

from __future__ import annotations

import re

from conftest import ROOT

README = (ROOT / "README.md").read_text()


def test_readme_opens_with_the_two_commands_and_ci_runs_the_second():
    block = re.search(r"```\n(.*?)```", README, re.S).group(1).strip().splitlines()
    assert len(block) == 2
    assert "elastoplast solve" in block[0]
    assert "pytest" in block[1]
    assert block[1] in (ROOT / ".ci" / "run").read_text()


def test_python_blocks_run(monkeypatch):
    monkeypatch.chdir(ROOT)
    for code in re.findall(r"```python\n(.*?)```", README, re.S):
        exec(compile(code, "README.md", "exec"), {})
