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
    """Executed with nbclient in the repository's root (as its first cell says), its bundle and figures under a
    temporary folder: every cell runs, the searcher and the genie both report, and a trajectory is drawn."""
    nbformat = pytest.importorskip("nbformat", reason="nbformat missing (pip install -e '.[test]')")
    nbclient = pytest.importorskip("nbclient", reason="nbclient missing (pip install -e '.[test]')")
    pytest.importorskip("ipykernel", reason="ipykernel missing (pip install -e '.[test]')")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:  # the outputs under tmp_path, not the repository's runs/
        cell.source = cell.source.replace('Path("runs/quickstart")', f"Path({str(tmp_path / 'quickstart')!r})")
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(REPO)}}).execute()
    text = "\n".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "tiny@" in text and "map searcher:" in text and "genie:" in text
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 2  # the city and the trajectory
