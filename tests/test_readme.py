"""The README's set-up commands, its problem file and the Python blocks of the README
and of the user's pages in docs/ are what they claim, and running them from the test
suite writes nothing into the repository."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import tomllib

import elastoplast.cli.commands as cli
from elastoplast.cli.main import main
from elastoplast.io.output import OUTPUT_MARKER
from elastoplast.problem.definition import read_toml

from conftest import ROOT
from test_cli import write_toml

README = (ROOT / "README.md").read_text()
#: the manual's pages whose ```python blocks run as they stand (the README's do too)
USER_PAGES = ("docs/loading-paths.md",)
COMMANDS = re.search(r"```\n(.*?)```", README, re.S).group(1).strip().splitlines()
#: what the repository may gain while tests run: the environment, caches, build metadata
NOT_SOURCE = {".git", ".venv", "__pycache__", ".pytest_cache", ".ipynb_checkpoints"}


def repository_files() -> dict[str, tuple[int, int]]:
    """``path -> (size, mtime_ns)`` of every file in the repository, caches and the
    environment aside: a test that writes a file, or overwrites one, changes it."""
    files = {}
    for folder, dirs, names in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in NOT_SOURCE and not d.endswith(".egg-info")]
        for name in names:
            st = os.stat(os.path.join(folder, name))
            files[os.path.relpath(os.path.join(folder, name), ROOT)] = (st.st_size, st.st_mtime_ns)
    return files


def test_readme_opens_with_the_two_commands_and_ci_runs_the_second():
    assert len(COMMANDS) == 2
    assert "elastoplast solve" in COMMANDS[0]
    assert "pytest" in COMMANDS[1]
    assert COMMANDS[1] in (ROOT / ".ci" / "run").read_text()


def test_first_command_writes_into_the_working_directory_only(tmp_path, monkeypatch, capsys):
    """The README's ``elastoplast solve --out results`` (on a coarser copy of the
    default problem) writes ``results/`` into the test's working directory and
    leaves every file of the repository as it was."""
    argv = shlex.split(COMMANDS[0].split("elastoplast ", 1)[1])
    assert argv[:3] == ["solve", "--out", "results"]
    data = read_toml(cli.default_problem_path())
    data["mesh"]["divisions"] = [6, 6, 3]
    monkeypatch.setattr(cli, "default_problem_path", lambda: write_toml(tmp_path / "default.toml", data))
    before = repository_files()
    assert main(argv) == 0
    capsys.readouterr()
    after = repository_files()
    assert sorted(set(after) - set(before)) == []  # no new file
    assert sorted(p for p in before if after.get(p) != before[p]) == []  # none rewritten
    assert {p.name for p in (tmp_path / "results").iterdir()} == {"solution.vtu", "summary.json", OUTPUT_MARKER}


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, re.S)


def test_python_blocks_run(tmp_path):
    """Each Python block of the README and of the user's pages runs from a copy of the
    folders it names, in the test's working directory (the blocks use paths relative to
    the repository root). The README must hold a block that solves and certifies, and
    docs/loading-paths.md one that solves a path: a page without it fails here, rather
    than passing with nothing run."""
    blocks = {"README.md": python_blocks(README)}
    blocks |= {page: python_blocks((ROOT / page).read_text()) for page in USER_PAGES}
    assert any("import elastoplast as ep" in code and "ep.solve(" in code and "ep.certify(" in code
               for code in blocks["README.md"]), "README.md has no ```python block that solves and certifies with elastoplast"
    assert any("ep.solve_path(" in code for code in blocks["docs/loading-paths.md"]), \
        "docs/loading-paths.md has no ```python block that solves a loading path"
    shutil.copytree(ROOT / "problems", tmp_path / "problems")
    for page, codes in blocks.items():
        for code in codes:
            exec(compile(code, page, "exec"), {})


def test_readme_problem_file_is_the_shipped_one():
    """The README's ```toml block is the file it says it is: the same keys and values
    as problems/cylinder_2d.toml, read by the package's own reader."""
    block = re.search(r"```toml\n(.*?)```", README, re.S).group(1)
    named = re.search(r"`(problems/[a-z0-9_]+\.toml)`[^`]*:\s*```toml", README).group(1)
    assert tomllib.loads(block) == read_toml(ROOT / named)


def test_links_of_the_readme_and_docs_resolve():
    """Every relative link of README.md and docs/*.md names a file or folder that exists:
    the manual moved out of the README, and a page renamed or a module moved must not
    leave a reader at a dead link."""
    dead = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue  # a web address or an anchor on the same page
            if not (page.parent / target.split("#")[0]).exists():
                dead.append(f"{page.relative_to(ROOT)}: {target}")
    assert dead == []
