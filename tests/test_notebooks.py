"""The notebooks run end to end: each ``notebooks/*.py`` (jupytext py:percent) is executed.

The ``.ipynb`` a user opens is paired with the ``.py`` text that is reviewed; the test
checks that the two hold the same cells, then runs the notebook in a fresh kernel
from the ``notebooks/`` folder. A notebook whose front matter says
``needs_shared: true`` is skipped, with the reason, where ``../shared`` is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import REPO_ROOT

jupytext = pytest.importorskip("jupytext")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((REPO_ROOT / "notebooks").glob("[0-9][0-9]_*.py"))


def _cells(nb) -> list[tuple[str, str]]:
    return [(c.cell_type, c.source.strip()) for c in nb.cells]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_pair_in_sync(path: Path):
    ipynb = path.with_suffix(".ipynb")
    assert ipynb.exists(), f"{ipynb.name} missing: run `jupytext --sync {path.name}`"
    assert _cells(jupytext.read(path)) == _cells(jupytext.read(ipynb)), (
        f"{path.name} and {ipynb.name} differ: run `jupytext --sync {path.name}`")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path: Path):
    from frictionfit.datasets import shared_dir

    nb = jupytext.read(path)
    if nb.metadata.get("frictionfit", {}).get("needs_shared") and shared_dir() is None:
        pytest.skip(f"{path.name} needs ../shared beside the repository; it is absent")
    client = nbclient.NotebookClient(
        nb, timeout=900, kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    client.execute()
