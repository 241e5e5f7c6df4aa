"""The notebooks run end to end: each ``notebooks/*.py`` (jupytext py:percent) is executed.

The ``.ipynb`` a user opens is paired with the ``.py`` text that is reviewed; the test
checks that the two hold the same cells, then runs the notebook in a fresh kernel
from the ``notebooks/`` folder. A notebook whose front matter says
``needs_shared: true`` is skipped, with the reason, where ``../shared`` is absent.

A notebook's conclusions ("## What we learned") must quote what it prints: every
decimal number there must be among the numbers of its outputs, to the quoted precision
(a percentage may quote a printed fraction). The stored ``.ipynb`` is checked as kept, and
each run is checked again, so a change of the fits that moves a quoted number fails
here instead of leaving the text behind. A notebook whose front matter says
``quotes_one_run: true`` (timings of one machine) is exempt from the check of the run.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

jupytext = pytest.importorskip("jupytext")
nbclient = pytest.importorskip("nbclient")
nbformat = pytest.importorskip("nbformat")

NOTEBOOKS = sorted((REPO_ROOT / "notebooks").glob("[0-9][0-9]_*.py"))


def _cells(nb) -> list[tuple[str, str]]:
    return [(c.cell_type, c.source.strip()) for c in nb.cells]


CONCLUSIONS = "## What we learned"
_QUOTED = re.compile(r"(?<![\w.])(\d+\.\d+)(?![\w.])(\s*%)?")
_PRINTED = re.compile(r"\d*\.?\d+(?:[eE][-+]?\d+)?")


def _printed(nb) -> np.ndarray:
    """Every number in the notebook's code outputs (text, plain or HTML)."""
    texts = []
    for cell in nb.cells:
        for out in cell.get("outputs", []) if cell.cell_type == "code" else []:
            texts.append(out.get("text", ""))
            texts += [v for k, v in out.get("data", {}).items()
                      if k in ("text/plain", "text/html", "text/markdown")]
    return np.array([float(x) for t in texts for x in _PRINTED.findall("".join(t))])


def unprinted_quotes(nb, ulp: float = 0.5) -> list[str]:
    """The decimal numbers of the conclusions that no output shows to within ``ulp`` units
    of their last quoted digit (``x %`` may also quote a printed ``x / 100``)."""
    printed = _printed(nb)
    missing = []
    for cell in nb.cells:
        at = cell.source.find(CONCLUSIONS) if cell.cell_type == "markdown" else -1
        for match in _QUOTED.finditer(cell.source[at:] if at >= 0 else ""):
            text, percent = match.groups()
            tol = ulp * 10.0 ** -len(text.split(".")[1]) + 1e-12
            values = [float(text)] + ([float(text) / 100] if percent else [])
            scales = [1.0] + ([0.01] if percent else [])
            if not any(np.any(np.abs(printed - v) <= tol * s)
                       for v, s in zip(values, scales, strict=True)):
                missing.append(text + (percent or ""))
    return missing


def _has_conclusions(nb) -> bool:
    return any(c.cell_type == "markdown" and CONCLUSIONS in c.source for c in nb.cells)


def test_unprinted_quotes_are_found():
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell(outputs=[nbformat.v4.new_output(
            "stream", text="accuracy 0.625, stderr/value 0.0256, tau 1.47 s\n")]),
        nbformat.v4.new_markdown_cell(f"{CONCLUSIONS}\nfitted 0.63, 2.6 % of its value, "
                                      "physical 0.597, 12 classes, 1.46 s at 30 %")])
    assert unprinted_quotes(nb) == ["0.597", "1.46"]
    assert unprinted_quotes(nb, ulp=1.0) == ["0.597"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_pair_in_sync(path: Path):
    ipynb = path.with_suffix(".ipynb")
    assert ipynb.exists(), f"{ipynb.name} missing: run `jupytext --sync {path.name}`"
    assert _cells(jupytext.read(path)) == _cells(jupytext.read(ipynb)), (
        f"{path.name} and {ipynb.name} differ: run `jupytext --sync {path.name}`")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_stored_conclusions_quote_the_stored_outputs(path: Path):
    nb = jupytext.read(path.with_suffix(".ipynb"))
    if not _printed(nb).size:
        pytest.skip(f"{path.with_suffix('.ipynb').name} keeps no outputs")
    assert _has_conclusions(nb), f"{path.name} has no '{CONCLUSIONS}' cell"
    assert not unprinted_quotes(nb), (
        f"{path.name}'s conclusions quote {unprinted_quotes(nb)}, which none of its stored "
        "outputs shows: rewrite them from what the notebook prints")


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
    if nb.metadata.get("frictionfit", {}).get("quotes_one_run"):
        return
    # one unit of the last quoted digit: another machine may round a printed value across
    # the quoted one's half-way point
    missing = unprinted_quotes(nb, ulp=1.0)
    assert not missing, (
        f"{path.name}'s conclusions quote {missing}, which this run does not print: the "
        "numbers moved; execute the notebook again and rewrite its conclusions")
