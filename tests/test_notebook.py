"""The quickstart notebook (examples/quickstart.ipynb) runs from start to end on the embedded tiny city, and is kept
in git without outputs."""

from __future__ import annotations

import json

import pytest

from tests.conftest import REPO

NOTEBOOK = REPO / "examples" / "quickstart.ipynb"


def test_the_notebook_is_kept_without_outputs():
    doc = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    code = [c for c in doc["cells"] if c["cell_type"] == "code"]
    assert code and all(not c["outputs"] and c["execution_count"] is None for c in code)


def test_the_quickstart_notebook_runs(tmp_path):
    """Executed with nbclient in the notebook's own folder, as `jupyter execute examples/quickstart.ipynb` runs it
    (from the repository's root or from examples/: its kernel starts in examples/), its bundle and figures under a
    temporary folder: it finds the repository, every cell runs, the searcher and the genie both report, and a
    trajectory is drawn."""
    nbformat = pytest.importorskip("nbformat", reason="nbformat missing (pip install -e '.[test]')")
    nbclient = pytest.importorskip("nbclient", reason="nbclient missing (pip install -e '.[test]')")
    pytest.importorskip("ipykernel", reason="ipykernel missing (pip install -e '.[test]')")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:  # the outputs under tmp_path, not the repository's runs/
        cell.source = cell.source.replace('REPO / "runs" / "quickstart"', f"Path({str(tmp_path / 'quickstart')!r})")
    assert any(str(tmp_path) in cell.source for cell in nb.cells)
    folder = {"metadata": {"path": str(NOTEBOOK.parent)}}
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources=folder).execute()
    text = "\n".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "tiny@" in text and "map searcher:" in text and "genie:" in text
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 2  # the city and the trajectory


def test_the_notebook_names_a_command_the_test_install_has():
    """The command the notebook says to run it with is installed by the README's test command (the test extra's
    nbclient and jupyter_core give `jupyter execute`)."""
    import shutil
    import sys
    from pathlib import Path

    text = json.loads(NOTEBOOK.read_text(encoding="utf-8"))["cells"][0]["source"]
    assert "jupyter execute examples/quickstart.ipynb" in "".join(text)
    pytest.importorskip("nbclient", reason="nbclient missing (pip install -e '.[test]')")
    assert shutil.which("jupyter-execute", path=str(Path(sys.executable).parent)) is not None
