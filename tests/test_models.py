"""The contact-model family: gradients, nesting, stability at extreme parameters."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.models import FAMILY, PARAMS, contact_force, get_model
from frictionfit.models.relaxation import maxwell_step

T = jnp.arange(2000) / 1000.0
VALUES = dict(offset=0.1, k=8.0, f_kin=0.6, f_static_excess=0.4, slip_length=0.05,
              relax_frac=0.3, tau=0.15, relax_frac2=0.2, tau2=1.2, damping=5e-3,
              delay=0.02, ramp=0.12)


def _u(model):
    return jnp.array([PARAMS[n].to_unconstrained(VALUES[n]) for n in model.param_names])


@pytest.mark.parametrize("model", FAMILY, ids=lambda m: m.name)
def test_gradient_matches_central_differences(model):
    # A scalar loss of the residual: smooth at this point (no clip boundary is crossed
    # by the small steps), so forward-mode and central differences agree to ~1e-6.
    y = model.predict(_u(model), T, (0.05, 1.05), 1.0) + 0.01 * jnp.sin(50 * T)

    def loss(u):
        return jnp.sum((model.predict(u, T, (0.05, 1.05), 1.0) - y) ** 2)

    u = _u(model) + 0.05
    grad = np.asarray(jax.grad(loss)(u))
    h = 1e-6
    fd = np.array([(loss(u.at[i].add(h)) - loss(u.at[i].add(-h))) / (2 * h)
                   for i in range(u.size)])
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())


def test_family_is_nested():
    # Switching off each member's extra effect gives the smaller member exactly.
    x = 1.0 * (0.5 - 0.5 * jnp.cos(jnp.pi * jnp.clip(T / 0.12, 0, 1)))
    base = contact_force(x, 1e-3, 8.0, 0.6)
    np.testing.assert_array_equal(contact_force(x, 1e-3, 8.0, 0.6, 0.0, 0.05), base)
    np.testing.assert_array_equal(contact_force(x, 1e-3, 8.0, 0.6, 0.0, 0.05, 0.0, 0.2), base)
    names = [m.name for m in FAMILY]
    assert names == ["elastic_plastic", "stick_slip", "relaxation", "rich"]
    pairs = zip(FAMILY[:-1], FAMILY[1:], strict=True)
    assert all(set(a.param_names) < set(b.param_names) for a, b in pairs)


def test_static_peak_and_kinetic_plateau():
    x = jnp.linspace(0, 1, 1000)
    f = np.asarray(contact_force(x, 1e-3, 20.0, 0.5, 0.3, 0.02))
    assert f.max() == pytest.approx(0.8, rel=1e-3)  # static = kinetic + excess
    assert f[-1] == pytest.approx(0.5, rel=1e-3)  # weakened to kinetic


@pytest.mark.parametrize("tau", [1e-9, 1e-4, 1.0, 1e6, 1e12])
def test_maxwell_step_is_stable_for_any_tau(tau):
    w = maxwell_step(jnp.array(0.0), jnp.array(0.0), jnp.array(1.0), 1e-3, tau)
    assert np.isfinite(w) and -1e-12 <= float(w) <= 1.0 + 1e-12


def test_very_stiff_contact_is_finite_with_finite_gradient():
    m = get_model("relaxation")
    u = _u(m).at[m.param_names.index("k")].set(PARAMS["k"].to_unconstrained(9.9e3))
    y = m.predict(u, T, (0.05, 1.05), 1.0)
    g = jax.jacfwd(lambda v: m.predict(v, T, (0.05, 1.05), 1.0))(u)
    assert np.all(np.isfinite(y)) and np.all(np.isfinite(g))


def test_param_transforms_round_trip_and_respect_bounds():
    for p in PARAMS.values():
        v = p.to_physical(p.to_unconstrained(p.default))
        assert v == pytest.approx(p.default, rel=1e-9, abs=1e-12)
        if p.transform != "identity":
            assert p.lower <= p.to_physical(np.float64(50.0)) <= p.upper
            assert p.lower <= p.to_physical(np.float64(-50.0)) <= p.upper


def test_unknown_model_and_drive_are_named():
    with pytest.raises(ValueError, match="unknown model 'foo'"):
        get_model("foo")
    with pytest.raises(ValueError, match="drive must be"):
        get_model("stick_slip", drive="wobble")


def test_absent_effect_equals_switched_off_effect():
    # None leaves an effect out of the recurrence; it must equal the effect at zero.
    x = 1.0 * (0.5 - 0.5 * jnp.cos(jnp.pi * jnp.clip(T / 0.12, 0, 1)))
    full = contact_force(x, 1e-3, 8.0, 0.6, 0.4, 0.05, 0.3, 0.15, 0.0, 1.0, 0.0, 0.0)
    lean = contact_force(x, 1e-3, 8.0, 0.6, 0.4, 0.05, 0.3, 0.15)
    np.testing.assert_allclose(lean, full, rtol=0, atol=1e-14)


def test_a_drive_simulated_in_pieces_from_the_state_left_is_one_history():
    x = 1.0 * (0.5 - 0.5 * jnp.cos(jnp.pi * jnp.clip(T / 0.12, 0, 1)))
    x = jnp.concatenate([x, x[::-1], x])
    law = (8.0, 0.6, 0.4, 0.05, 0.3, 0.15, 0.2, 2.0, 1e-3)
    whole = contact_force(x, 1e-3, *law)
    pieces, state = [], None
    for a, b in ((0, 37), (37, 400), (400, x.size)):
        f, state = contact_force(x[a:b], 1e-3, *law, state=state, return_state=True)
        pieces.append(f)
    np.testing.assert_allclose(jnp.concatenate(pieces), whole, rtol=1e-13, atol=1e-15)


def test_worn_kinetic_level_is_f_kin_halfway_through_the_travel():
    # Four 1-mm strokes out and back: the plateau of each stroke falls by exp(-wear) per mm
    # travelled, and equals f_kin at half the total travel (2 mm).
    one = jnp.linspace(0.0, 1.0, 500)
    x = jnp.concatenate([one, one[::-1], one, one[::-1]])
    wear = 0.05
    f = np.asarray(contact_force(x, 1e-3, 50.0, 0.6, wear=wear))
    travel = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(x)))])
    sliding = np.arange(x.size) % 500 >= 50  # each stroke after its loading
    level = 0.6 * np.exp(wear * (2.0 - travel))
    np.testing.assert_allclose(np.abs(f[sliding]), level[sliding], rtol=1e-12)
    assert np.abs(f[sliding]).max() > 0.6 * np.exp(0.09)  # a fresh textile grips more


def test_ramp_shape_is_the_raised_cosine_to_rounding_with_its_derivative():
    from frictionfit.models.stick_slip import ramp_shape

    u = jnp.linspace(-0.3, 1.3, 20001)
    np.testing.assert_allclose(ramp_shape(u), 0.5 - 0.5 * jnp.cos(jnp.pi * jnp.clip(u, 0, 1)),
                               rtol=0, atol=4e-16)
    slope = jax.vmap(jax.grad(ramp_shape))(u)
    inside = (u > 0) & (u < 1)
    exact = jnp.where(inside, 0.5 * jnp.pi * jnp.sin(jnp.pi * u), 0.0)
    np.testing.assert_allclose(slope, exact, rtol=0, atol=2e-15)


def test_a_model_is_found_again_by_its_name():
    from frictionfit.models.measurement import LAWS, MeasurementModel, model_named

    for law in LAWS:
        assert model_named(MeasurementModel(law).name) == MeasurementModel(law)
    for name in ("stick_slip", "relaxation"):
        assert model_named(name) == get_model(name)
    with pytest.raises(ValueError, match="unknown law 'nope'"):
        model_named("measurement-nope")
