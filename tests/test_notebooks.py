"""The notebooks are executed by `pytest --nbmake notebooks` (.ci/run's slow tier); here we
check what nbmake does not: outputs are cleared and each runs at its small size by default."""

from pathlib import Path

import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 2


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_clean_and_quick(path):
    nb = nbformat.read(str(path), as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(not c.get("outputs") for c in code), f"{path.name}: clear the outputs"
    assert all(c.get("execution_count") is None for c in code), f"{path.name}: clear counts"
    src = "\n".join(c.source for c in code)
    assert "QUICK = True" in src, f"{path.name}: the suite runs notebooks at a small size"
    assert "import lionjax" in src
