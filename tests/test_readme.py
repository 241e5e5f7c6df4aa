"""The README's tour runs as written: its Python blocks, in order, from the repository root
(the sample recordings in ``data/``)."""

from __future__ import annotations

import contextlib
import io
import os
import re

import numpy as np
from conftest import REPO_ROOT


def _tour() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (REPO_ROOT / "README.md").read_text(), re.S)


def test_the_tour_runs_as_written():
    blocks = _tour()
    assert len(blocks) >= 2, "the README's tour lost its Python blocks"
    namespace: dict = {}
    printed = io.StringIO()
    cwd = os.getcwd()
    try:
        os.chdir(REPO_ROOT)
        with contextlib.redirect_stdout(printed):
            for block in blocks:
                exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102
    finally:
        os.chdir(cwd)
    out = printed.getvalue()
    assert out.count("[[Model]]") == 2 and "[[BIC by model]]" in out
    # the whole fit measures the stiffness of every channel; the posterior covers each row
    assert np.isfinite(namespace["res"].values["k"]).all()
    assert set(namespace["post"].method) == {"laplace"}
