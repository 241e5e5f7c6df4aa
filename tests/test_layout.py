"""Package-wide conventions: lint, the import-layer contract, a light CLI."""

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
        "import sys, tempfile; from typer.testing import CliRunner;"
        "from frictionfit.cli import app; import frictionfit.whole_fit;"
        "r = CliRunner().invoke(app, ['fit', tempfile.mkdtemp(), '--out',"
        "                             tempfile.mkdtemp() + '/fits.csv']);"
        "assert 'no recording could be fitted' in r.output, r.output;"
        "print('emcee' in sys.modules, 'scipy.stats' in sys.modules)").split() == ["False", "False"]
