"""notebooks/results.ipynb runs top to bottom on a tiny evaluation and shows its tables, plots and meshes."""

import os
import sys
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[2] / "notebooks" / "results.ipynb"


def test_results_notebook_executes_on_a_tiny_evaluation(evaluated_dir, monkeypatch, tmp_path):
    # The kernel spec runs `python`: make that the interpreter running the tests (the venv's).
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.setenv("USHAPE_EVAL_DIR", str(evaluated_dir))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        notebook, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs) + "".join(
        o.get("data", {}).get("text/markdown", "") for o in outputs
    )
    assert "Table 3: multi-view fusion" in text and "Table S1" in text
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 4 + 2 + 1  # the saved plots, the redrawn calibration curves, the mesh panel
