"""Every notebook runs top to bottom on the public API (nbclient), and is committed with the outputs of such a
run, so that it reads as a page when browsed (refresh: ``jupyter execute --inplace notebooks/*.ipynb``)."""

from pathlib import Path

import pytest
from helpers import require

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def _nb_modules():
    return require("nbclient"), require("nbformat")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    nbclient, nbformat = _nb_modules()
    # The kernel inherits TMPDIR: what the notebooks write with tempfile lands in pytest's folder, removed with it.
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


def test_notebooks_are_committed_with_the_outputs_of_a_clean_run():
    nbformat = _nb_modules()[1]
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        cells = [c for c in nb.cells if c.cell_type == "code"]
        # run top to bottom in one kernel: execution counts 1, 2, 3, ... and no error output
        assert [c.get("execution_count") for c in cells] == list(range(1, len(cells) + 1)), path.name
        assert not [o for c in cells for o in c.get("outputs", []) if o.output_type == "error"], path.name
        assert any(c.get("outputs") for c in cells), path.name
