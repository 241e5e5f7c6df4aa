"""The compiled loops (the value with its forward-mode Jacobian, the value alone) agree with
JAX's channel scan and its ``jacfwd``."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.models import MeasurementModel
from frictionfit.models._forward import channel_jacobian, channel_values
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
