"""The compiled loops (the value with its forward-mode Jacobian, the value alone) agree with
JAX's channel scan and its ``jacfwd``; as XLA's operations they give the same numbers and
their programs are kept in JAX's persistent cache."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.models import MeasurementModel, _xla
from frictionfit.models._forward import (
    channel_jacobian,
    channel_values,
    weighted_normal_equations,
)
from frictionfit.models.measurement import LAWS, _channel_fn

VALUES = dict(offset=0.1, drift=0.01, leak=0.05, k=8.0, f_kin=0.6, f_static_excess=0.4,
              slip_length=0.05, relax_frac=0.3, tau=0.15, relax_frac2=0.4, tau2=1.2,
              damping=5e-3, wear=0.05, drag=0.02, delay=0.01, ramp=0.12, accel=0.1)


def _movements(seed: int):
    """A non-uniform grid (1 ms moving, 10 ms holding) over a stroke out and back, with a
    hold between, each movement its own duration."""
    ms = np.concatenate([np.arange(0, 300), np.arange(300, 1000, 10),
                         np.arange(1000, 1300), np.arange(1300, 2000, 10)])
    stretch = 1 + 0.1 * np.random.default_rng(seed).standard_normal(2)
    return ms / 1000.0, np.array([0.05, 1.05]), np.array([1.0, -1.0]), stretch


@pytest.mark.parametrize("law", list(LAWS))
def test_channel_and_jacobian_match_jacfwd_of_the_scan(law):
    names = MeasurementModel(law).param_names
    channel = _channel_fn(law, 1.3, None)
    rng = np.random.default_rng(1)
    rows = []
    for seed in range(3):  # a batch: each row its own movements, parameters and sign
        data = _movements(seed) + (float(rng.choice([-1.0, 1.0])),)
        theta = (np.array([VALUES[n] for n in names])
                 * np.exp(0.3 * rng.standard_normal(len(names))))
        theta[names.index("accel")] = 0.1 + 0.3 * rng.random()  # its range: (0, 0.5)
        rows.append((theta, *data, channel(jnp.asarray(theta), *data),
                     jax.jacfwd(channel)(jnp.asarray(theta), *data)))
    theta, t, cmd, signs, stretch, direction, want_v, want_j = (
        np.stack(a) for a in zip(*rows, strict=True))
    value, jac = channel_jacobian(theta, t, cmd, signs, stretch, direction,
                                  names=LAWS[law], stroke_mm=1.3, rig_columns=True)
    assert jac.shape == want_j.shape and np.abs(want_j).max(axis=(0, 1)).min() > 0
    np.testing.assert_allclose(value, want_v, rtol=1e-12, atol=1e-12 * np.abs(want_v).max())
    scale = np.abs(want_j).max(axis=(0, 1))  # per column: each parameter's own unit
    np.testing.assert_allclose(jac / scale, want_j / scale, rtol=0, atol=1e-11)
    # the value alone (its twin loop, coefficients reused while the interval holds)
    alone = channel_values(theta, t, cmd, signs, stretch, direction, names=LAWS[law],
                           stroke_mm=1.3)
    np.testing.assert_allclose(alone, want_v, rtol=0, atol=1e-11 * np.abs(want_v).max())
    # a held rig: the same value and columns, the rig's left 0
    v0, j0 = channel_jacobian(theta, t, cmd, signs, stretch, direction,
                              names=LAWS[law], stroke_mm=1.3, rig_columns=False)
    np.testing.assert_array_equal(v0, value)
    np.testing.assert_array_equal(j0[..., :-3], jac[..., :-3])
    assert not j0[..., -3:].any()


def _batch(law: str, lead: tuple[int, ...]):
    """Inputs of ``law``'s channel with leading axes ``lead`` (the grid of
    :func:`_movements`, each row its own parameters, movements' durations and sign)."""
    names = MeasurementModel(law).param_names
    rng = np.random.default_rng(7)
    rows = []
    for seed in range(int(np.prod(lead))):
        t, cmd, signs, stretch = _movements(seed)
        theta = (np.array([VALUES[n] for n in names])
                 * np.exp(0.3 * rng.standard_normal(len(names))))
        y = 0.1 * rng.standard_normal(t.size)
        rows.append((theta, t, cmd, signs, stretch, float(rng.choice([-1.0, 1.0])), y,
                     1.0 + rng.random(t.size)))
    return [np.stack(a).reshape(*lead, *np.shape(a[0])) for a in zip(*rows, strict=True)]


@pytest.mark.parametrize(("law", "one_thread"), [("relaxation2", False), ("no_peak2", False),
                                               ("relaxation2", True)])
def test_xla_targets_give_the_loops_numbers_jitted_and_vmapped(law, one_thread, monkeypatch):
    """``one_thread``: the serial loops, as where numba has only its ``workqueue`` layer."""
    if one_thread:
        monkeypatch.setattr(_xla, "threads", lambda: 1)
    theta, t, cmd, signs, stretch, direction, y, weight = _batch(law, (2, 3))
    kw = dict(names=LAWS[law], stroke_mm=1.3)
    want_v, want_j = channel_jacobian(theta, t, cmd, signs, stretch, direction,
                                      rig_columns=True, **kw)
    want_n = weighted_normal_equations(theta, t, cmd, signs, stretch, direction, y, weight,
                                       rig_columns=False, **kw)
    # the rows' own leading axes, and the same through vmap over the first axis
    for wrap in (jax.jit, lambda f: jax.jit(jax.vmap(f))):
        value = wrap(lambda *a: _xla.values(*a, **kw))(theta, t, cmd, signs, stretch,
                                                     direction)
        v, j = wrap(lambda *a: _xla.jacobian(*a, rig_columns=True, **kw))(
            theta, t, cmd, signs, stretch, direction)
        normal = wrap(lambda *a: _xla.normal_equations(*a, rig_columns=False, **kw))(
            theta, t, cmd, signs, stretch, direction, y, weight)
        np.testing.assert_array_equal(value, channel_values(theta, t, cmd, signs, stretch,
                                                            direction, **kw))
        np.testing.assert_array_equal(v, want_v)
        np.testing.assert_array_equal(j, want_j)
        for got, want in zip(normal, want_n, strict=True):
            np.testing.assert_array_equal(got, want)
    empty = jax.jit(lambda *a: _xla.values(*a, **kw))(*(a[:0, 0] for a in (
        theta, t, cmd, signs, stretch, direction)))
    assert empty.shape == (0, t.shape[-1])


def test_xla_targets_reject_inputs_without_the_rows_leading_axes():
    theta, t, cmd, signs, stretch, direction, _, _ = _batch("no_peak2", (2,))
    with pytest.raises(ValueError, match="leading axes"):
        _xla.values(theta[:1], t, cmd, signs, stretch, direction, names=LAWS["no_peak2"],
                    stroke_mm=1.3)


def test_a_program_calling_the_loop_is_kept_in_the_persistent_cache(tmp_path):
    """A new process loads it instead of compiling it (a host callback would keep it out)."""
    script = textwrap.dedent("""
        import jax, numpy as np
        import frictionfit.models  # sets up the persistent cache
        from frictionfit.models import _xla
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        t = np.linspace(0.0, 1.0, 50)[None]
        # sensor; no_peak2's k, f_kin, two branches, wear; drag; rig
        theta = np.array([[0.0, 0, 0, 8.0, 0.6, 0.3, 0.15, 0.2, 1.0, 0.0, 0.01, 0.01, 0.12,
                           0.1]])
        def contact_program(theta, t):
            return _xla.values(theta, t, t[:, :1] + 0.1, t[:, :1] ** 0, t[:, :1] ** 0,
                               t[:, 0] ** 0, names=("k", "f_kin", "relax_frac", "tau",
                                                     "relax_frac2", "tau2", "wear"),
                               stroke_mm=1.0)
        print(float(jax.jit(contact_program)(theta, t).sum()))
    """)
    env = os.environ | {"FRICTIONFIT_JAX_CACHE": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                           text=True, check=True).stdout for _ in range(2)]
    assert runs[0] == runs[1] and np.isfinite(float(runs[0]))
    assert list(tmp_path.glob("jit_contact_program-*"))


def _channel_sum(inputs) -> float:
    return float(channel_values(*inputs, names=LAWS["no_peak2"], stroke_mm=1.3).sum())


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
def test_a_forked_process_computes_the_channel_after_its_parent_used_the_xla_target():
    """The NumPy path starts threads of its own in a child (its parent's are gone) and never
    enters numba's threading layer, which OpenMP does not let a forked process use."""
    import multiprocessing

    inputs = _batch("no_peak2", (4,))[:6]
    jax.jit(lambda *a: _xla.values(*a, names=LAWS["no_peak2"], stroke_mm=1.3))(*inputs)
    _channel_sum(inputs)  # the parent's pool started
    with multiprocessing.get_context("fork").Pool(2) as pool:
        got = pool.map_async(_channel_sum, [inputs, inputs]).get(timeout=120)
    assert got == [_channel_sum(inputs)] * 2
