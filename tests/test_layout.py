"""Package-wide conventions: lint, the import-layer contract, a light CLI, docstrings
without measured figures, functions and modules of a readable length."""

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT


def _tool(name):
    beside = Path(sys.executable).with_name(name)
    return str(beside) if beside.exists() else shutil.which(name) or pytest.fail(f"{name} missing")


def test_ruff_clean():
    ruff = _tool("ruff")
    out = subprocess.run([ruff, "check", "frictionfit", "tests"], cwd=REPO_ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_import_layers_contract():
    tool = _tool("lint-imports")
    out = subprocess.run([tool], cwd=REPO_ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def _python(code: str) -> str:
    """Run ``code`` in a fresh interpreter; its standard output."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_cli_help_does_not_import_jax():
    assert _python(
        "import sys; from typer.testing import CliRunner; from frictionfit.cli import app;"
        "r = CliRunner().invoke(app, ['--help']); assert r.exit_code == 0, r.output;"
        "assert 'info' in r.output; print('jax' in sys.modules)").strip() == "False"


def test_entry_points_import_from_the_package_lazily():
    assert _python(
        "import sys, frictionfit; jax_at_import = 'jax' in sys.modules;"
        "from frictionfit import fit_trials, sample_posterior, segment, make_pipeline;"
        "from frictionfit import fit_recordings;"
        "print(jax_at_import, callable(fit_trials) and callable(make_pipeline)"
        "      and callable(fit_recordings))"
    ).split() == ["False", "True"]


def test_a_fit_without_posteriors_imports_neither_emcee_nor_scipy_stats():
    # scipy.stats (which emcee imports) takes ~0.7 s of every process that fits
    assert _python(
        "import sys, tempfile, numpy as np; from typer.testing import CliRunner;"
        "from frictionfit.cli import app; import frictionfit.whole_fit;"
        "from frictionfit import Recording, write_recording; d = tempfile.mkdtemp();"
        "write_recording(Recording.from_arrays(np.ones((3000, 2)), 1000.0,"
        "                ['thumb_x', 'index_x']), d + '/dead.csv');"  # dead channels: no fit
        "r = CliRunner().invoke(app, ['fit', d, '--out', tempfile.mkdtemp() + '/fits.csv']);"
        "assert 'no recording could be fitted' in r.output, r.output;"
        "print('emcee' in sys.modules, 'scipy.stats' in sys.modules)").split() == ["False", "False"]


# Docstrings say what the code does, its units and its contract: measured figures, timings
# and pointers into the design log live in docs/ (docs/results.md, docs/decisions.md).
_FIGURES = re.compile(r"\bmeasured\b|\b\d+(\.\d+)?x (faster|slower|cheaper|dearer)|decisions\.md")
#: The benchmarks measure: their docstrings may say what and how.
_FIGURES_EXEMPT = ("bench",)


def _area(path: Path) -> str:
    """A package file's area: its sub-package, or "modules" for the top-level modules."""
    parts = path.relative_to(REPO_ROOT / "frictionfit").parts
    return parts[0] if len(parts) > 1 else "modules"


def _docstring_figures(path: Path) -> list[str]:
    """``file:line name: match`` of every docstring in ``path`` that quotes a figure. Inline
    code (````measured=True````) and numpydoc parameter lines (``measured : bool``) name
    code, not measurements, and are left out."""
    hits = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                 ast.AsyncFunctionDef)):
            continue
        text = ast.get_docstring(node, clean=True) or ""
        text = re.sub(r"``.*?``", "", text, flags=re.S)
        text = re.sub(r"(?m)^\s*[\w*, ]+ : .*$", "", text)
        hits += [f"{path.name}:{getattr(node, 'lineno', 1)} "
                 f"{getattr(node, 'name', '<module>')}: {m.group(0)!r}"
                 for m in _FIGURES.finditer(text)]
    return hits


_AREAS = sorted({_area(p) for p in (REPO_ROOT / "frictionfit").rglob("*.py")}
                - set(_FIGURES_EXEMPT))


@pytest.mark.parametrize("area", _AREAS)
def test_docstrings_quote_no_measurements(area):
    files = sorted(p for p in (REPO_ROOT / "frictionfit").rglob("*.py") if _area(p) == area)
    hits = [h for p in files for h in _docstring_figures(p)]
    assert not hits, "measured figures belong in docs/, not docstrings:\n" + "\n".join(hits)


def test_the_figures_check_finds_what_it_names(tmp_path):
    # the check itself: prose is caught, code names are not
    probe = tmp_path / "probe.py"
    probe.write_text('"""Fits 5x faster (see docs/decisions.md); measured on the lab.\n\n'
                     'Parameters\n----------\nmeasured : bool\n    ``measured=True``.\n"""\n')
    hits = _docstring_figures(probe)
    assert [h.rsplit(": ", 1)[1] for h in hits] == ["'5x faster'", "'decisions.md'",
                                                    "'measured'"]


#: Longest function (def line to the body's last line, docstring included) anywhere in the
#: package, and longest module of the fit and model layers, in lines.
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 400
_SIZED_AREAS = ("fit", "models")


def _too_long(path: Path, sized: bool) -> list[str]:
    """``file:line name: n lines`` of every function in ``path`` over
    :data:`MAX_FUNCTION_LINES`, and of the module itself over :data:`MAX_MODULE_LINES`
    where ``sized``."""
    text = path.read_text()
    hits = [f"{path.name}:{node.lineno} {node.name}: {node.end_lineno - node.lineno + 1} lines"
            for node in ast.walk(ast.parse(text))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    n_lines = len(text.splitlines())
    if sized and n_lines > MAX_MODULE_LINES:
        hits.append(f"{path.name}: module of {n_lines} lines")
    return hits


def test_functions_and_modules_stay_short():
    package = REPO_ROOT / "frictionfit"
    hits = [h for p in sorted(package.rglob("*.py"))
            for h in _too_long(p, _area(p) in _SIZED_AREAS)]
    assert not hits, (f"split by meaning: functions over {MAX_FUNCTION_LINES} lines, modules "
                      f"of fit/ and models/ over {MAX_MODULE_LINES}:\n" + "\n".join(hits))


def test_the_length_check_finds_what_it_names(tmp_path):
    probe = tmp_path / "probe.py"
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    probe.write_text(f"def long():\n{body}\n\ndef short():\n    return 1\n"
                     + "\n" * MAX_MODULE_LINES)
    assert _too_long(probe, sized=False) == [f"probe.py:1 long: {MAX_FUNCTION_LINES + 1} lines"]
    assert _too_long(probe, sized=True)[-1].startswith("probe.py: module of ")
    probe.write_text("def short():\n    return 1\n")
    assert _too_long(probe, sized=True) == []
