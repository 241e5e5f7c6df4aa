"""A whole fit's least-squares problem on a stacked batch, and its log posterior.

:class:`WholeFitData` holds a batch of channels (:class:`~frictionfit.fit.measurement_data.
MeasurementData`) padded to one grid, one row per item. :func:`residual_fn` is the fit's
residual (weighted block residuals, then the priors scaled by the item's noise sd, so the
least-squares optimum is the MAP estimate under white noise of that sd);
:func:`normal_fn` its normal equations. The log posterior of a whole fit is
``-|residual|^2 / (2 s2)``, ``s2`` the long-run variance of the item's AR(1) noise
(:func:`~frictionfit.fit._noise.long_run_variance`): the one likelihood's form for whole
fits, whose maximum is the fit's optimum. emcee and the checks of a flagged ridge evaluate
it; the fit's covariance is the sandwich around that optimum (:func:`score_covariances`).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.fit._noise import long_run_covariance
from frictionfit.fit._numerics import map_chunks
from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import jit_host_loop

__all__ = ["WholeFitData", "cost_fn", "normal_fn", "profile_drops", "residual_fn",
           "residuals_at", "score_covariances", "stack_items"]


class WholeFitData(eqx.Module):
    """A batch of channels on one padded grid (every field one row per item).

    ``y`` (n_items, N): block means (N) at times ``t`` (s); ``weight``: the square root of
    each block's sample count (0: not fitted, and the padding); ``commands`` (n_items, M,
    s), ``signs`` and ``stretch`` of each movement (padding commands never come);
    ``direction`` (+1/-1) and ``noise`` (the sd of one sample, N) per item; ``base``
    (n_items, p): the unconstrained parameters that a fit holds (the free ones are
    overwritten).
    """

    y: np.ndarray
    weight: np.ndarray
    t: np.ndarray
    commands: np.ndarray
    signs: np.ndarray
    stretch: np.ndarray
    direction: np.ndarray
    noise: np.ndarray
    base: np.ndarray

    @property
    def mask(self):
        """The blocks fitted."""
        return self.weight > 0

    def take(self, rows) -> WholeFitData:
        """The items ``rows`` (an index array, or one index: one item, no leading axis)."""
        return jax.tree_util.tree_map(lambda a: a[rows], self)


def stack_items(items: Sequence[MeasurementData], base: np.ndarray) -> WholeFitData:
    """The batch as a :class:`WholeFitData`: past its end an item's grid goes on in 1-ms
    steps with weight 0."""
    n = max(d.y.size for d in items)
    m = max(d.commands.size for d in items)

    def pad(a, size, step=0.0):
        tail = (a[-1] if step else 0.0) + step * np.arange(1, size - a.size + 1)
        return np.concatenate([a, tail])

    never = [np.r_[np.zeros(d.commands.size), np.full(m - d.commands.size, 1e9)] for d in items]
    return WholeFitData(
        y=np.stack([pad(d.y, n) for d in items]),
        weight=np.stack([pad(d.weight, n) for d in items]),
        t=np.stack([pad(d.t, n, 1e-3) for d in items]),
        commands=np.stack([pad(d.commands, m) + late for d, late in zip(items, never,
                                                                         strict=True)]),
        signs=np.stack([pad(d.signs, m) for d in items]),
        stretch=np.stack([np.r_[d.stretch, np.ones(m - d.commands.size)] for d in items]),
        direction=np.array([d.direction for d in items]),
        noise=np.array([d.noise for d in items]), base=np.asarray(base))


def _full(data: WholeFitData, free: tuple[int, ...], u_free):
    return data.base.at[jnp.asarray(free)].set(u_free)


def _held(model: MeasurementModel, free: tuple[int, ...]) -> tuple[str, ...]:
    return tuple(n for j, n in enumerate(model.param_names) if j not in free)


@lru_cache(maxsize=16)
def residual_fn(model: MeasurementModel, free: tuple[int, ...]):
    """``residual(u_free, data)`` of one item over the ``free`` parameters (the others from
    ``data.base``): weighted block residuals (0 where not fitted), then the priors scaled
    by the item's noise sd."""
    held = _held(model, free)

    def residual(u_free, data: WholeFitData):
        u = _full(data, free, u_free)
        pred = model.predict(u, data.t, data.commands, data.signs, data.direction, held,
                             data.stretch)
        return jnp.concatenate([data.weight * (pred - data.y),
                                data.noise * model.prior_residuals(u)])

    return residual


@lru_cache(maxsize=16)
def normal_fn(model: MeasurementModel, free: tuple[int, ...]):
    """``normal(u_free, data) -> (|r|^2 / 2, J^T J, J^T r)`` of :func:`residual_fn`'s
    residual: the data rows' part from :meth:`MeasurementModel.normal_equations` (on the
    host, no ``(n, p)`` Jacobian in JAX), the priors' by ``jacfwd``."""

    def normal(u_free, data: WholeFitData):
        def priors(w):
            return data.noise * model.prior_residuals(_full(data, free, w))

        cost, jtj, jtr = model.normal_equations(
            _full(data, free, u_free), data.t, data.commands, data.signs, data.direction,
            data.y, data.weight, free, data.stretch)
        rp, jp = priors(u_free), jax.jacfwd(priors)(u_free)
        return cost + 0.5 * rp @ rp, jtj + jp.T @ jp, jtr + jp.T @ rp

    return normal


@lru_cache(maxsize=16)
def cost_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted ``(points (m, q), data) -> (m,)``: ``|residual|^2 / 2`` (priors included) at
    each of ``points`` of one item."""
    residual = residual_fn(model, free)
    return jit_host_loop(lambda points, data: jax.vmap(
        lambda w: 0.5 * jnp.sum(residual(w, data) ** 2))(points))


def profile_drops(model: MeasurementModel, free: tuple[int, ...], u_free: np.ndarray,
                  cov: np.ndarray, data: WholeFitData, s2: np.ndarray, rows) -> np.ndarray:
    """Per item of ``rows``, ``(len(rows), 2, q)``: the fall of the log posterior
    ``-|residual|^2 / (2 s2)`` from ``u_free`` to 2 sd out on the + and - side of each free
    parameter's Gaussian profile line (its column of ``cov``); a Gaussian falls by exactly
    2. ``s2``: per item, the long-run noise variance (N^2). NaN where the residual is not
    finite."""
    cost = cost_fn(model, free)
    q = len(free)
    out = np.full((len(rows), 2, q), np.nan)
    for k, i in enumerate(rows):
        line = (cov[i] / np.sqrt(np.maximum(np.diag(cov[i]), 1e-300))).T  # row j: j's line
        points = np.concatenate([u_free[i][None], u_free[i] + 2 * line, u_free[i] - 2 * line])
        c = np.asarray(cost(points, data.take(i)))
        out[k] = ((c[1:] - c[0]) / s2[i]).reshape(2, q)
    return out


@lru_cache(maxsize=16)
def _residuals_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted, vmapped ``(u_free, data) -> weighted block residuals`` of a chunk of items."""
    residual = residual_fn(model, free)
    return jit_host_loop(jax.vmap(lambda w, data: residual(w, data)[: data.y.shape[-1]]))


#: Items per call where the residuals at the solutions are evaluated.
RESIDUAL_CHUNK = 16


def residuals_at(model: MeasurementModel, free: tuple[int, ...], u_free: np.ndarray,
                 data: WholeFitData) -> np.ndarray:
    """Weighted block residuals (N) of every item at ``u_free``, in chunks of
    :data:`RESIDUAL_CHUNK` items."""
    return map_chunks(_residuals_fn(model, free), (u_free, data), RESIDUAL_CHUNK)


#: Forward-difference step of the scores' Jacobian, in each free parameter's ``u``.
SCORE_STEP = 1e-6


def score_covariances(model: MeasurementModel, free: tuple[int, ...], u_free: np.ndarray,
                      data: WholeFitData, resid: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Per item ``(q, q)``: the long-run covariance of the blocks' scores ``J_t r_t``
    (:func:`~frictionfit.fit._noise.long_run_covariance`; ``J_t`` the weighted block's
    Jacobian row over the free parameters at ``u_free`` by forward differences of step
    :data:`SCORE_STEP` from ``resid`` through the residuals' own loop, ``r_t`` its residual
    ``resid`` at ``u_free``, N; ``rho`` the residuals' lag-one coefficient), in chunks of
    :data:`RESIDUAL_CHUNK` items."""
    residuals = _residuals_fn(model, free)
    q = u_free.shape[1]
    steps = SCORE_STEP * np.eye(q)

    def chunk(u, d, r, rh):
        u = np.asarray(u)
        points = (u[:, None, :] + steps).reshape(-1, q)
        rows = np.repeat(np.arange(len(u)), q)
        moved = np.asarray(residuals(points, jax.tree_util.tree_map(lambda a: a[rows], d)))
        r = np.asarray(r)
        jac = np.moveaxis(moved.reshape(len(u), q, -1) - r[:, None], 1, 2) / SCORE_STEP
        return long_run_covariance(jac * r[..., None], np.asarray(d.weight) > 0,
                                   np.asarray(rh))

    return map_chunks(chunk, (u_free, data, resid, rho), RESIDUAL_CHUNK)
