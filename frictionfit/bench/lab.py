"""Whole fits of a folder of lab recordings, where no truth is known.

A lab folder (``frictionfit.datasets.rubbing_lab``) carries no truth to recover, so the fits
are scored by what a measurement of the material must do without one:

- converge, with the stiffness ``k`` and the kinetic level ``f_kin`` determined (neither
  flagged);
- be one law for the whole recording: the spread of ``k`` and ``f_kin`` over its motions,
  each motion refitted alone (the fit's ``per_motion()``), as
  sd / median;
- measure the material, not the day: the classes' median log values agree between sessions
  (Pearson over the classes two sessions share, mean over the pairs);
- rank the materials as the model-free measurements do: per material (one layer), the
  median fitted ``k`` against the measured onset rate and the fitted ``f_kin`` against the
  measured held level (:func:`~frictionfit.features.physical.measured_phase`; Spearman).

Speed: the whole fits of every channel, fitted twice in one process; the second is timed
(every program the fits take is compiled by then: JAX keeps none of the whole fits'
programs between processes, and a few recordings do not take every path).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from frictionfit.bench.timing import machine_info
from frictionfit.datasets.rubbing_lab import load
from frictionfit.errors import Status
from frictionfit.features.physical import FITTED_CHANNELS, PhysicalFeatures
from frictionfit.fit.measurement_data import measurement_data
from frictionfit.models.measurement import NAME_PREFIX
from frictionfit.whole_fit import fit_recordings

__all__ = ["DETERMINED", "FITS", "run"]

#: The parameters a lab fit must determine.
DETERMINED = ("k", "f_kin")
#: The spread over motions the goal allows (sd / median).
SPREAD_GOAL = 0.05
#: The fits scored, by name: the default law choice per channel, the same with the motor's
#: profile held at each session's median (``rig="session"``), and the fitted features' fit
#: (one law, the kinetic level's ``wear`` held at 0).
FITS = {"auto": {"model": "auto"},
        "auto, rig per session": {"model": "auto", "rig": "session"},
        "relaxation2, wear 0": {"model": "relaxation2", "fix": {"wear": 0.0}}}


def run(path: str | Path, *, quick: bool = False, seed: int = 0,
        channels: Sequence[str] = FITTED_CHANNELS) -> dict:
    """Fit every recording of the folder ``path`` whole (``quick``: every 20th) on
    ``channels`` by each of :data:`FITS` and score the fits (module notes); the summary's
    ``lab_*`` numbers are the default law choice's. ``seed`` is not used (the fits are
    deterministic); it is accepted as every stage's is."""
    del seed
    recordings = load(path)[::20] if quick else load(path)
    if not recordings:
        raise ValueError(f"{path}: no readable recording")
    items = [measurement_data(r, ch) for r in recordings for ch in channels]
    features = PhysicalFeatures(fitted=False).fit(recordings)
    measured = pd.DataFrame(features.transform(recordings),
                            columns=features.get_feature_names_out())
    scores = {name: _score(items, recordings, channels, kw, measured)
              for name, kw in FITS.items()}
    default = scores["auto"]
    summary = {f"lab_{key}": default[key] for key in (
        "channels", "fit_s", "channels_per_s", "compile_s", "converged_rate",
        "converged_key_unflagged_rate")} | {"lab": scores}
    points = [{"config": f"whole fits, {name}", "seconds_per_trial": 1 / s["channels_per_s"],
               "error": 1.0 - s["converged_key_unflagged_rate"],
               "error_name": "1 - converged with k and f_kin unflagged"}
              for name, s in scores.items()]
    return {"stage": "lab", "summary": summary, "points": points,
            "machine": machine_info(), "dataset": str(path)}


def _score(items, recordings, channels: Sequence[str], fit_kw: dict,
           measured: pd.DataFrame) -> dict:
    """Fit ``items`` by ``fit_recordings(**fit_kw)`` twice, the second timed, and score the
    fits (module notes); ``compile_s``: how much longer the first took."""
    first = fit_recordings(items, **fit_kw, progress=False)
    fit = fit_recordings(items, **fit_kw)
    compile_s = max(first.wall_s - fit.wall_s, 0.0)
    motions = fit.per_motion(progress=None)
    item_of = motions.item_of
    table = _per_item(recordings, channels, fit)
    converged = table["status"] == Status.CONVERGED
    determined = converged & ~table[[f"{p}_flagged" for p in DETERMINED]].any(axis=1)
    by_channel = _agreement(table)
    for ch, ranks in _ranks(table, measured, channels).items():
        by_channel[ch] |= ranks
    return {"channels": len(items), "fit_s": fit.wall_s,
            "channels_per_s": len(items) / fit.wall_s, "compile_s": compile_s,
            "converged_rate": float(converged.mean()),
            "converged_key_unflagged_rate": float(determined.mean()),
            "laws": table["law"].value_counts().to_dict(),
            "flagged_by_param": {p: int(table[f"{p}_flagged"].sum()) for p in DETERMINED},
            "motion_spread_by_param": _spread(motions, item_of),
            "by_channel": by_channel}


def _per_item(recordings, channels: Sequence[str], fit) -> pd.DataFrame:
    """One row per fitted channel: its recording's metadata, law, status, key values
    (log10) and whether each is flagged."""
    rows = []
    for i, (rec, ch) in enumerate((r, c) for r in recordings for c in channels):
        row = {"channel": ch, "label": rec.label, "material": rec.metadata.get("material"),
               "layers": rec.metadata.get("layers"), "session": rec.metadata.get("session"),
               "law": fit.model[i].removeprefix(NAME_PREFIX), "status": int(fit.status[i])}
        for p in DETERMINED:
            value = fit.values.at[i, p]
            row[p] = np.log10(value) if value > 0 else np.nan
            row[f"{p}_flagged"] = p in fit.flags[i]
        rows.append(row)
    return pd.DataFrame(rows)


def _spread(motions, item_of: np.ndarray) -> dict:
    """Per key parameter, the sd / median of its values over each item's refitted motions:
    median over items and share within :data:`SPREAD_GOAL`."""
    out = {}
    for p in DETERMINED:
        values = motions.values[p].to_numpy()
        spread = np.array([np.std(v, ddof=1) / np.median(np.abs(v))
                           for v in (values[item_of == i] for i in np.unique(item_of))
                           if v.size > 1])
        out[p] = {"median": float(np.nanmedian(spread)),
                  "within_goal": float(np.mean(spread <= SPREAD_GOAL)), "items": spread.size}
    return out


def _agreement(table: pd.DataFrame) -> dict:
    """Per channel, for each key parameter ``p``, ``agreement_<p>``: the Pearson correlation
    of the classes' median log values between two sessions, mean over the session pairs
    (NaN with one session)."""
    out: dict = {}
    for ch, part in table.groupby("channel", sort=False):
        medians = part.groupby(["session", "label"])[list(DETERMINED)].median()
        sessions = sorted(part["session"].dropna().unique())
        out[ch] = {}
        for p in DETERMINED:
            r = [medians.loc[a, p].to_frame("a").join(medians.loc[b, p].rename("b"),
                                                      how="inner").corr().iloc[0, 1]
                 for a, b in combinations(sessions, 2)]
            out[ch][f"agreement_{p}"] = float(np.nanmean(r)) if r else np.nan
    return out


def _ranks(table: pd.DataFrame, measured: pd.DataFrame, channels: Sequence[str]) -> dict:
    """Per channel, Spearman over the one-layer materials of the median fitted ``k`` against
    the median measured onset rate, and of ``f_kin`` against the measured held level (both
    strokes' magnitudes, mean); ``measured``: the recordings' measured features."""
    out: dict = {}
    for ch, part in table.groupby("channel", sort=False):
        pick = [f"{ch}:{phase}_{name}" for phase in ("out", "back")
                for name in ("onset_rate [N/s]", "static [N]")]
        rows = measured.iloc[[i // len(channels) for i in part.index]].reset_index(drop=True)
        frame = part.reset_index(drop=True).assign(
            onset=rows[pick[0]].abs().to_numpy() / 2 + rows[pick[2]].abs().to_numpy() / 2,
            held=rows[pick[1]].abs().to_numpy() / 2 + rows[pick[3]].abs().to_numpy() / 2)
        one = frame[frame["layers"] == 1].groupby("material").median(numeric_only=True)
        out[ch] = {"rank_k_vs_onset_rate": float(spearmanr(one["k"], one["onset"]).statistic),
                   "rank_f_kin_vs_held": float(spearmanr(one["f_kin"], one["held"]).statistic),
                   "materials": len(one)}
    return out
