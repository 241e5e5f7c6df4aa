"""PNG of one trial: data and fitted curve above, residuals below (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from frictionfit.errors import Status
from frictionfit.fit.result import FitResult

__all__ = ["plot_fit"]


def plot_fit(result: FitResult, i: int, t, y, path, title: str | None = None) -> Path:
    """Write a PNG of trial ``i``: data (N) vs. fit against time (s), and the residuals.

    Parameters
    ----------
    result : FitResult
        The batch result (from :func:`frictionfit.fit.fit_trials`).
    i : int
        Trial index.
    t, y : array (n_samples,)
        Sample times (s) and the trial's force (N, NaN where missing).
    path : str or Path
        Output file (``.png``).
    title : str, optional
        The trial's name in the title (e.g. ``recording/motion1/index_x``); default
        ``trial <i>``.

    Returns
    -------
    Path
        The file written.
    """
    from frictionfit._optional import pyplot

    plt = pyplot("plot_fit")

    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    fit = result.predict(i, t)
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5),
                                      gridspec_kw={"height_ratios": [3, 1]})
    top.plot(t, y, ".", ms=2, color="0.5", label="data")
    top.plot(t, fit, "-", color="C3", lw=1.5, label=f"fit: {result.model[i]}")
    status = Status(int(result.status[i])).name.lower()
    top.set_title(f"{title or f'trial {i}'}: {status}, R^2 = {result.r2[i]:.4f}")
    top.set_ylabel("force [N]")
    top.legend(loc="best")
    bottom.plot(t, y - fit, ".", ms=2, color="C0")
    bottom.axhline(0.0, color="k", lw=0.8)
    bottom.set_xlabel("time [s]")
    bottom.set_ylabel("residual [N]")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
