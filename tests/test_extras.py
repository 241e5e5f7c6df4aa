"""The core install and its extras: every module imports without the extras, and what needs
one names it (``pip install "frictionfit[<extra>]"``)."""

from __future__ import annotations

import subprocess
import sys

import pytest
import typer
from conftest import REPO_ROOT

from frictionfit._optional import EXTRAS, MissingExtraError, lazy_module, pyplot, require

#: Prepended to a child interpreter's code: the extras' modules cannot be found, as in a
#: core install.
_WITHOUT_EXTRAS = f"""
import sys
class _Hide:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {sorted({*EXTRAS, "dask"})!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, _Hide())
"""


def _core(code: str) -> subprocess.CompletedProcess:
    """``code`` run in a fresh interpreter without the extras' modules."""
    return subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS + code], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=600)


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib", reason="Python 3.11 reads TOML")
    return tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())


def test_every_extra_is_declared_and_kept_out_of_the_core():
    project = _pyproject()["project"]
    extras, core = project["optional-dependencies"], " ".join(project["dependencies"])
    for module, (package, extra) in EXTRAS.items():
        assert any(req.startswith(package) for req in extras[extra]), (module, extra)
        assert package not in core, f"{package} is optional ({extra}) but in the core"
    names = sorted({extra for _, extra in EXTRAS.values()})
    assert extras["all"] == [f"frictionfit[{','.join(names)}]"]
    assert "frictionfit[all]" in extras["test"]


def test_a_missing_module_names_its_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import of pyarrow halted
    with pytest.raises(MissingExtraError, match=r'writing Parquet needs pyarrow.*'
                                                r'pip install "frictionfit\[store\]"'):
        require("pyarrow", "writing Parquet")
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtraError, match=r"frictionfit\[plots\]") as err:
        pyplot("a PNG")
    assert isinstance(err.value, ImportError) and err.value.extra == "plots"
    serial = lazy_module("serial", "The sensor")  # nothing imported until it is used
    monkeypatch.setitem(sys.modules, "serial", None)
    with pytest.raises(MissingExtraError, match=r"The sensor needs pyserial"):
        serial.serial_for_url("loop://")


def test_a_failure_inside_an_installed_extra_is_not_called_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    with pytest.raises(ModuleNotFoundError) as err:
        require("matplotlib.pyplot", "a PNG")  # matplotlib is there; one of its parts is not
    assert not isinstance(err.value, MissingExtraError)


def test_an_output_whose_writer_is_missing_is_refused_before_any_work(monkeypatch, tmp_path):
    from frictionfit.cli._load import check_writable

    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(typer.BadParameter, match=r'pip install "frictionfit\[store\]"'):
        check_writable(tmp_path / "fits.parquet", "--out", (".csv", ".parquet"))
    check_writable(tmp_path / "fits.csv", "--out", (".csv", ".parquet"))


def test_every_module_imports_without_the_extras():
    # a core install must be able to import the whole package: extras load where used (not
    # marked slow, ~10 s: CI runs "not slow", and this is what keeps the core install whole)
    out = _core("import importlib, pkgutil, frictionfit\n"
                "for m in pkgutil.walk_packages(frictionfit.__path__, 'frictionfit.'):\n"
                "    importlib.import_module(m.name)\n"
                "print('ok')")
    assert out.stdout.strip() == "ok", out.stderr


def test_the_command_line_names_the_missing_extra(tmp_path):
    rec = REPO_ROOT / "data" / "s1_paper-1_01.csv"
    out = _core("import os, sys\n"
                f"os.chdir({str(tmp_path)!r})\n"
                f"sys.argv = ['frictionfit', 'plot', {str(rec)!r}]\n"
                "from frictionfit.cli import main\n"
                "main()")
    assert out.returncode == 1, out.stderr
    assert out.stderr.strip() == ('error: frictionfit plot needs matplotlib, which is not '
                                  'installed: pip install "frictionfit[plots]"')


def test_the_acquisition_imports_without_pyserial_and_opens_no_port_without_it():
    out = _core("from frictionfit.acquisition import OptoForceSensor, FrameParser\n"
                "from frictionfit._optional import MissingExtraError\n"
                "try:\n"
                "    OptoForceSensor('loop://').open()\n"
                "except MissingExtraError as exc:\n"
                "    print(exc)")
    assert out.stdout.strip() == ('The OptoForce sensor needs pyserial, which is not '
                                  'installed: pip install "frictionfit[acquisition]"'), out.stderr


def test_the_benchmarks_load_only_when_they_run():
    # the NumPy/scipy peers of `frictionfit bench` stay out of `import frictionfit.bench`
    # and of the command line's start
    out = subprocess.run(
        [sys.executable, "-c",
         "import sys, frictionfit.bench, frictionfit.cli;"
         "print(sorted(m for m in sys.modules if m.startswith('frictionfit.bench.')"
         " or m in ('scipy', 'jax', 'sklearn')))"],
        capture_output=True, text=True)
    assert out.stdout.strip() == "[]", out.stderr
