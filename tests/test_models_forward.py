"""The compiled forward-mode loop agrees with JAX's ``jacfwd`` of the contact scan."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.models import contact_force
from frictionfit.models._forward import contact_jacobian
from frictionfit.models.measurement import LAWS, _travel

VALUES = dict(k=8.0, f_kin=0.6, f_static_excess=0.4, slip_length=0.05, relax_frac=0.3,
              tau=0.15, relax_frac2=0.4, tau2=1.2, damping=5e-3, wear=0.05)


def _drive(seed: int):
    """A non-uniform grid (1 ms moving, 10 ms holding) with holds and reversals, a travel
    that depends on three drive parameters, and its derivative in them."""
    ms = np.concatenate([np.arange(0, 300), np.arange(300, 1000, 10),
                         np.arange(1000, 1300), np.arange(1300, 2000, 10)])
    t = jnp.asarray(ms / 1000.0)
    cmd, signs = jnp.array([0.05, 1.05]), jnp.array([1.0, -1.0])
    rig = jnp.array([0.01, 0.12, 0.1]) * (1 + 0.1 * np.random.default_rng(seed).random(3))

    def travel(r):
        return _travel(1.0, *r, t, cmd, signs, jnp.ones(2))[0]

    dt = jnp.diff(t, prepend=2 * t[0] - t[1])
    return travel, rig, dt


@pytest.mark.parametrize("law", list(LAWS))
def test_force_and_jacobian_match_jacfwd_of_the_scan(law):
    names = LAWS[law]
    rng = np.random.default_rng(1)
    rows = []
    for seed in range(3):  # a batch: each row its own drive and parameters
        travel, rig, dt = _drive(seed)
        p = np.array([VALUES[n] for n in names]) * np.exp(0.3 * rng.standard_normal(len(names)))

        def force(theta, travel=travel, dt=dt):
            return contact_force(travel(theta[len(names):]), dt,
                                 **dict(zip(names, theta[:len(names)], strict=True)))

        theta = jnp.concatenate([jnp.asarray(p), rig])
        rows.append((travel(rig), jax.jacfwd(travel)(rig), dt, p, force(theta),
                     jax.jacfwd(force)(theta)))
    x, xdot, dt, p, want_f, want_j = (np.stack(a) for a in zip(*rows, strict=True))
    f, j = contact_jacobian(x, xdot, dt, p, names)
    assert j.shape == want_j.shape and np.abs(want_j).max(axis=(0, 1)).min() > 0
    np.testing.assert_allclose(f, want_f, rtol=1e-12, atol=1e-12 * np.abs(want_f).max())
    scale = np.abs(want_j).max(axis=(0, 1))  # per column: each parameter's own unit
    np.testing.assert_allclose(j / scale, want_j / scale, rtol=0, atol=1e-11)
    # without drive directions: the law's columns alone, the same numbers
    f0, j0 = contact_jacobian(x, xdot[..., :0], dt, p, names)
    np.testing.assert_array_equal(f0, f)
    np.testing.assert_array_equal(j0, j[..., :len(names)])
