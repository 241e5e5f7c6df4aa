"""The whole fits' two paths: the compiled loop (its XLA target on the CPU, numba on the
host) and the pure-JAX reference (JAX's scan and ``jacfwd``, on any backend), chosen by
``FRICTIONFIT_NATIVE`` and by the installed jaxlib's FFI layout, give the same numbers."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.models import MeasurementModel, _ffi, _xla, measurement
from frictionfit.models.measurement import LAWS, to_unconstrained
from tests.test_models_forward import VALUES, _movements


@pytest.fixture
def path(monkeypatch):
    """``path(native)``: the compiled loop (True) or the pure-JAX path (False) from now on."""

    def choose(native: bool):
        monkeypatch.setenv("FRICTIONFIT_NATIVE", "1" if native else "0")
        _xla.usable.cache_clear()
        measurement._channel_fn.cache_clear()

    yield choose
    monkeypatch.delenv("FRICTIONFIT_NATIVE")
    _xla.usable.cache_clear()
    measurement._channel_fn.cache_clear()


def _problem(law: str, seed: int = 0):
    """A law's model, unconstrained parameters near :data:`VALUES` and one channel's data
    (the grid of ``_movements``, each movement its own duration)."""
    model = MeasurementModel(law, 1.3)
    rng = np.random.default_rng(seed)
    u = to_unconstrained(model, VALUES) + 0.2 * rng.standard_normal(len(model.param_names))
    t, cmd, signs, stretch = _movements(seed)
    y = model.channel(u, t, cmd, signs, stretch, np.float64(-1.0)) + 0.01 * rng.standard_normal(
        t.size)
    return model, u, (t, cmd, signs, stretch, -1.0, y, 1.0 + rng.random(t.size))


def _numbers(model, u, data):
    """What a whole fit takes from the model: the channel's Jacobian in ``u`` (every
    parameter, then the rig held), the weighted normal equations, the movement timing's
    products and the host channel."""
    t, cmd, signs, stretch, direction, y, weight = data
    free = tuple(range(len(model.param_names) - 3))  # the rig held

    def jac(held):
        return jax.jit(jax.jacfwd(lambda v: model.predict(v, t, cmd, signs, direction, held,
                                                          stretch)))(jnp.asarray(u))

    normal = jax.jit(lambda v: model.normal_equations(v, t, cmd, signs, direction, y, weight,
                                                      free, stretch))(jnp.asarray(u))
    timing = model.timing_normal_equations(u, t, cmd, signs, stretch, direction, y, weight)
    host = model.channel(np.stack([u, u]), np.stack([t, t]), np.stack([cmd, cmd]),
                         np.stack([signs, signs]), np.stack([stretch, stretch]),
                         np.array([direction, direction]))
    return [np.asarray(a) for a in (jac(()), jac(("delay", "ramp", "accel")), *normal,
                                    *timing, host)]


def _agree(got, want, rtol):
    """Each array within ``rtol`` of the other, relative to its largest entry per last
    axis's column (a Jacobian's columns are each in their parameter's unit)."""
    scale = np.maximum(np.abs(want).reshape(-1, *want.shape[-1:]).max(axis=0), 1e-300) \
        if want.ndim > 1 else np.maximum(np.abs(want).max(), 1e-300)
    np.testing.assert_allclose(got / scale, want / scale, rtol=0, atol=rtol)


@pytest.mark.parametrize("law", list(LAWS))
def test_both_paths_give_the_same_jacobians_and_products_on_every_law(law, path):
    model, u, data = _problem(law)
    path(True)
    native = _numbers(model, u, data)
    path(False)
    pure = _numbers(model, u, data)
    assert np.abs(native[0]).max(axis=0).min() > 0  # every column moves the channel
    for got, want in zip(native, pure, strict=True):
        _agree(got, want, 1e-10)


def test_a_program_lowered_for_another_platform_runs_the_pure_path(monkeypatch, path):
    """Where JAX has an accelerator (here: as if it had), a whole fit's step exported for a
    GPU or TPU names no CPU target; its lowering for the CPU does."""
    model, u, (t, cmd, signs, stretch, direction, y, weight) = _problem("relaxation2")
    monkeypatch.setattr(_xla, "_cpu_only", lambda: False)
    path(True)

    def step(v):
        return model.normal_equations(v, t, cmd, signs, direction, y, weight, (0, 1, 3, 4),
                                      stretch)

    for platform in ("cuda", "rocm", "tpu"):
        text = jax.export.export(jax.jit(step), platforms=[platform])(jnp.asarray(u)).mlir_module()
        assert _xla.TARGET not in text and "stablehlo.while" in text
    lowered = jax.jit(step).lower(jnp.asarray(u)).as_text()
    assert _xla.TARGET in lowered and "stablehlo.while" not in lowered


def _fake_header(tmp_path, edit):
    """An include folder whose ``c_api.h`` is the installed one with ``edit`` applied."""
    text = _ffi.installed_header().read_text()
    folder = tmp_path / "xla" / "ffi" / "api"
    folder.mkdir(parents=True)
    (folder / "c_api.h").write_text(edit(text))
    return tmp_path


NEWER = (lambda text: re.sub(r"(#define XLA_FFI_API_MINOR) \d+", r"\1 9", text),
         r"knows XLA FFI 0\.1-0\.3; the installed jaxlib ships FFI 0\.9")
OLDER_MAJOR = (lambda text: re.sub(r"(#define XLA_FFI_API_MAJOR) \d+", r"\1 1", text),
               r"knows XLA FFI 0\.1-0\.3; the installed jaxlib ships FFI 1\.\d")
BUFFER = (lambda text: text.replace("  int64_t rank;\n  int64_t* dims;",
                                    "  int64_t rank;\n  int64_t strides;\n  int64_t* dims;"),
          r"ships FFI 0\.\d with another layout: XLA_FFI_Buffer\.dims at byte 48 \(expected "
          r"40\); XLA_FFI_Buffer_STRUCT_SIZE 56 \(expected 48\)")
FRAME = (lambda text: text.replace("  XLA_FFI_ExecutionStage stage;\n",
                                   "  XLA_FFI_ExecutionStage stage;\n  void* device;\n"),
         r"XLA_FFI_CallFrame\.args at byte 48 \(expected 40\)")


@pytest.mark.parametrize(("edit", "message"), [NEWER, OLDER_MAJOR, BUFFER, FRAME])
def test_a_jaxlib_of_another_ffi_layout_is_refused_naming_both(tmp_path, edit, message):
    assert _ffi.layout_problem() is None  # the installed one is known
    fake = _fake_header(tmp_path, edit)
    problem = _ffi.layout_problem(fake / "xla" / "ffi" / "api" / "c_api.h")
    assert problem is not None and re.search(message, problem), problem


def test_a_jaxlib_without_the_ffi_header_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(jax.ffi, "include_dir", lambda: str(tmp_path))
    assert "ships no xla/ffi/api/c_api.h" in _ffi.layout_problem()


def test_the_fits_fall_back_to_the_pure_path_where_the_layout_is_refused(tmp_path, monkeypatch,
                                                                        path):
    model, u, data = _problem("rich", seed=1)
    t, cmd, signs, stretch, direction, y, weight = data
    path(True)
    native = _numbers(model, u, data)
    fake = _fake_header(tmp_path, NEWER[0])
    monkeypatch.setattr(jax.ffi, "include_dir", lambda: str(fake))
    path(True)  # asked for, but the (fake) jaxlib's FFI is refused
    with pytest.warns(RuntimeWarning, match=r"compiled contact loop is off: .*" + NEWER[1]):
        assert not _xla.usable()
    fallback = _numbers(model, u, data)
    for got, want in zip(fallback, native, strict=True):
        _agree(got, want, 1e-10)
    step = jax.jit(lambda v: model.normal_equations(v, t, cmd, signs, direction, y, weight,
                                                    (0, 1), stretch))
    assert _xla.TARGET not in step.lower(jnp.asarray(u)).as_text()
    with pytest.raises(RuntimeError, match="XLA target is off"):
        _xla._registered.__wrapped__()


_WHOLE_FITS = """
import sys
import numpy as np
from frictionfit import fit_recordings, read_recording
recs = [read_recording(p) for p in sys.argv[2:]]
res = fit_recordings(recs, channels=("index_x", "thumb_x"), progress=False)
np.savez(sys.argv[1], values=res.values.to_numpy(float), columns=list(res.values.columns),
         model=res.model, bic=res.bic)
"""


def test_whole_fits_of_the_sample_recordings_end_at_the_same_optimum_both_ways(tmp_path):
    """Every sample recording's rubbing channels fitted whole (the default: law by BIC) by
    the compiled loop and by the pure-JAX path (``FRICTIONFIT_NATIVE=0``), each in its own
    process: >= 95 % of the fits' values within 1e-6 relative, the same laws."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    recordings = sorted(str(p) for p in (Path(__file__).parents[1] / "data").glob("*.csv"))
    assert recordings
    runs = {}
    for native in ("1", "0"):
        out = tmp_path / f"native-{native}.npz"
        subprocess.run([sys.executable, "-c", _WHOLE_FITS, str(out), *recordings], check=True,
                       env=os.environ | {"FRICTIONFIT_NATIVE": native})
        runs[native] = np.load(out)
    native, pure = runs["1"], runs["0"]
    assert list(native["columns"]) == list(pure["columns"])
    assert list(native["model"]) == list(pure["model"])
    a, b = native["values"], pure["values"]
    same_nan = np.isnan(a) == np.isnan(b)
    close = np.isclose(a, b, rtol=1e-6, atol=0) | (np.isnan(a) & np.isnan(b))
    agree = (close & same_nan).all(axis=1)
    names = [f"{Path(r).stem} {ch}" for r in recordings for ch in ("index_x", "thumb_x")]
    assert agree.mean() >= 0.95, [n for n, ok in zip(names, agree, strict=True) if not ok]
    np.testing.assert_allclose(native["bic"][agree], pure["bic"][agree], rtol=1e-6)
