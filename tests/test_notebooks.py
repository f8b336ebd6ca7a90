"""The notebooks run top to bottom as committed, use the public API only, and are committed
with their outputs (inline plots at a low resolution, no errors).

Each notebook's default size runs in about a minute; a named parameter in its first cell
scales it up (`LANES`, `ALL_CLAIMS`, `GRID_SIZE`). The kernel draws with the Agg backend here
(`MPLBACKEND`), so no display is needed; in Jupyter the plots are inline.
"""

import base64
import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))
IDS = [p.name for p in NOTEBOOKS]
MAX_IMAGE_BYTES = 80_000  # committed PNGs stay small (figure.dpi = 60)


def code_cells(book):
    return [cell for cell in book.cells if cell.cell_type == "code"]


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 4


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_runs(path, tmp_path, monkeypatch):
    book = nbformat.read(path, as_version=4)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    client = NotebookClient(book, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [o for c in code_cells(book) for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_uses_the_public_api_and_inline_plots(path):
    source = "\n".join(cell.source for cell in code_cells(nbformat.read(path, as_version=4)))
    assert not re.search(r"grazejax\._|from \._", source), "private grazejax module"
    assert "matplotlib.use(" not in source, "let Jupyter's inline backend draw"
    assert ".savefig(" not in source, "figures are shown inline, not written to files"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_is_committed_with_outputs(path):
    cells = code_cells(nbformat.read(path, as_version=4))
    assert all(cell.get("execution_count") is not None for cell in cells), "run every cell"
    counts = [cell.execution_count for cell in cells]
    assert counts == list(range(1, len(cells) + 1)), "run top to bottom in one kernel"
    outputs = [o for cell in cells for o in cell.get("outputs", [])]
    assert outputs and not [o for o in outputs if o.output_type == "error"]
    images = [o["data"]["image/png"] for o in outputs if "image/png" in o.get("data", {})]
    assert all(len(base64.b64decode(png)) < MAX_IMAGE_BYTES for png in images)
