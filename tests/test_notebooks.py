"""Every notebook in notebooks/ (jupytext percent-format .py) executes without error.

Run in small mode (ELASTOPLAST_NOTEBOOK_SMALL=1), with the Agg backend; the kernel
starts in the test's temporary folder, so anything a notebook writes lands there.
"""

import pytest

from conftest import ROOT

NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.py"))


def test_notebooks_exist():
    assert len(NOTEBOOKS) >= 3


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path, monkeypatch):
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("ELASTOPLAST_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = jupytext.read(path)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out.get("output_type") != "error"
            if out.get("output_type") == "stream":
                # nothing a reader must scroll past
                assert out["text"].count("\n") <= 12, f"{path.name} prints {out['text'].count(chr(10))} lines"
