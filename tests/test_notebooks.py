"""Every notebook executes top to bottom from its own folder (they are thin studies over the
library; ``pip install -e ".[notebook]"`` adds Jupyter). Outputs are not committed. The default
suite runs the quick start, the slow tier every notebook."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from tests.helpers import tiered

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_notebooks_are_committed_without_outputs():
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), path.name


@pytest.mark.parametrize("path", tiered(NOTEBOOKS, ("quickstart.ipynb",), ids=lambda p: p.name))
def test_notebook_runs_from_its_folder(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    # a copy of the folder's notebook runs in a scratch folder beside links to the scenarios and studies,
    # as it would in the notebook's own folder, so that its outputs land in the scratch folder
    work = tmp_path / "notebooks"
    work.mkdir()
    for folder in ("scenarios", "studies"):
        (tmp_path / folder).symlink_to(ROOT / folder)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(work)}}).execute()
    images = sum(1 for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
                 if "image/png" in o.get("data", {}))
    assert images >= 1, "the notebook's figures must show inline"
