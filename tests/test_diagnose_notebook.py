"""notebooks/03_sim_to_real.ipynb runs top to bottom (QUICK = True) without errors.

CI also runs it through ``pytest --nbmake notebooks``; this test keeps it covered by a plain
``pytest tests`` and checks what it prints."""

import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NB = Path(__file__).resolve().parents[1] / "notebooks" / "03_sim_to_real.ipynb"


def test_notebook_runs_quick(monkeypatch):
    import os

    root = str(NB.parents[1])  # the kernel imports this checkout's lionjax, installed or not
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))
    )
    nb = nbformat.read(str(NB), as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), "clear outputs"
    t0 = time.perf_counter()
    NotebookClient(
        nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(NB.parent)}}
    ).execute()
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "verdict: coulomb_friction" in text
    assert time.perf_counter() - t0 < 120
