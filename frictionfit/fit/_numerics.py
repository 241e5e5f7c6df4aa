"""Small numerics shared by the fit and the posterior: the delta method, normal equations,
scaled inverses and condition numbers of normal matrices, and evaluation in padded chunks."""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np

__all__ = ["DELTA_STEP", "fd_slope", "map_chunks", "normal_equations", "pad_rows",
           "scaled_condition", "scaled_pinv"]

#: Step of the central differences of the delta method (unconstrained units).
DELTA_STEP = 1e-6


def fd_slope(f: Callable, u, h: float = DELTA_STEP):
    """``df/du`` at ``u`` by a central difference, elementwise (the delta method's slope)."""
    return (f(u + h) - f(u - h)) / (2 * h)


def normal_equations(residual: Callable, x, has_aux: bool = False):
    """``(|r|^2 / 2, J^T J, J^T r)`` of ``residual`` at ``x`` (traced; a forward-mode
    Jacobian: few parameters, many residuals). ``has_aux``: ``residual`` returns ``(r,
    aux)``, and so does this, ``((|r|^2 / 2, J^T J, J^T r), aux)``."""
    def both(z):
        r, aux = residual(z) if has_aux else (residual(z), None)
        return r, (r, aux)

    jac, (r, aux) = jax.jacfwd(both, has_aux=True)(x)
    out = (0.5 * r @ r, jac.T @ jac, jac.T @ r)
    return (out, aux) if has_aux else out


def _unit_diagonal(a: np.ndarray):
    """``a (..., p, p)`` scaled to unit diagonal, and the outer product of the scales."""
    d = np.sqrt(np.maximum(np.diagonal(a, axis1=-2, axis2=-1), 1e-300))
    outer = d[..., :, None] * d[..., None, :]
    return a / outer, outer


def scaled_condition(a: np.ndarray) -> np.ndarray:
    """Condition number of each symmetric ``a (..., p, p)`` scaled to unit diagonal
    (inf unless positive definite; inf for ``p = 0``: nothing is determined)."""
    ev = np.linalg.eigvalsh(_unit_diagonal(a)[0])
    if ev.shape[-1] == 0:
        return np.full(ev.shape[:-1], np.inf)
    low = ev[..., 0]
    return np.where(low > 0, ev[..., -1] / np.where(low > 0, low, 1.0), np.inf)


def scaled_pinv(a: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """Pseudo-inverse of each symmetric ``a (..., p, p)``, taken at unit diagonal."""
    unit, outer = _unit_diagonal(a)
    return np.linalg.pinv(unit, rcond=rcond, hermitian=True) / outer


def pad_rows(idx: np.ndarray, size: int) -> np.ndarray:
    """``idx`` padded to ``size`` entries by repeating its last one (one compiled shape)."""
    return np.concatenate([idx, np.full(size - idx.size, idx[-1])])


def map_chunks(fn: Callable, args, chunk: int):
    """``fn(*args)`` over the rows of ``args`` (a tuple of pytrees whose leaves share the
    leading axis, at least one row), ``chunk`` rows per call (the last padded by
    :func:`pad_rows`: one compiled shape); the outputs (a pytree of arrays) trimmed and
    concatenated as NumPy arrays."""
    n = jax.tree_util.tree_leaves(args)[0].shape[0]
    parts = []
    for start in range(0, n, chunk):
        idx = np.arange(start, min(start + chunk, n))
        rows = pad_rows(idx, chunk)
        out = fn(*jax.tree_util.tree_map(lambda a, r=rows: a[r], args))
        parts.append(jax.tree_util.tree_map(lambda o, m=idx.size: np.asarray(o)[:m], out))
    return jax.tree_util.tree_map(lambda *o: np.concatenate(o), *parts)
