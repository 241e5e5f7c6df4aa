"""FabricSlide: a 16-taxel capacitive finger sliding along fabric strips (Wang et al. 2022).

One file per slide, ``<Fabric>_F<pressure>_V<speed>mmps_<rep>.csv`` (e.g.
``Linen_F180_V-10mmps_0.csv``), header ``timestamp, proximity1, proximity2,
channel1, ..., channel16``: integer milliseconds since the logger started, two
"proximity" words and 16 baseline-subtracted taxel readings (counts). Each slide
is a quarter-sine velocity ramp lasting 47.1 mm / ``|speed|`` (30 mm of travel), 500 mm
at constant ``|speed|`` and a ramp down of the same length, logged over exactly the motion.

Every recording has the 16 taxels as channels ``channel1..channel16`` followed by
``proximity1``, ``proximity2`` (all unit ``"counts"``); texture feature sets use
:data:`TAXELS` only. ``metadata`` holds ``label`` and ``fabric`` (the fabric name),
``pressure`` (grip set-point, counts), ``speed`` (mm/s, signed: negative is
downward), ``direction`` (``"down"``/``"up"``), ``repetition``, ``condition``
(``"F<p>_V<v>"``), ``ramp_s`` (duration of each velocity ramp, s),
``logger_start_ms`` and ``dataset="fabricslide"``.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from frictionfit._types import PathType
from frictionfit.errors import DatasetError, RecordingError
from frictionfit.recording import Channel, DatasetWarning, Problem, Recording

__all__ = ["PROXIMITY", "RAMP_SPEED_TIME_MM", "TAXELS", "load", "parse_name", "read_slide",
           "slide_duration_s"]

#: Taxel channel names, in file order.
TAXELS: tuple[str, ...] = tuple(f"channel{i}" for i in range(1, 17))
#: The two extra words the finger sends; kept, never used as texture.
PROXIMITY: tuple[str, ...] = ("proximity1", "proximity2")
COLUMNS: tuple[str, ...] = ("timestamp", *PROXIMITY, *TAXELS)
#: Ramp duration times |speed| (mm): each quarter-sine ramp lasts 47.1 mm / |v| (upstream
#: controller) and covers 2 x 47.1 / pi = 30 mm of travel.
RAMP_SPEED_TIME_MM = 47.1
#: Constant-speed travel (mm).
STEADY_TRAVEL_MM = 500.0
#: Fewest rows a slide may have (the fastest slides have ~141).
MIN_ROWS = 20
#: Shortest logged duration, as a share of :func:`slide_duration_s`, of a complete slide
#: (the shared recordings span 0.992-1.014 of it).
SHORTEST_SHARE = 0.95

_NAME = re.compile(
    r"^(?P<fabric>[A-Za-z]+)_F(?P<pressure>\d+)_V(?P<speed>[+-]?\d+)mmps_(?P<rep>\d+)\.csv$"
)


def parse_name(path: PathType) -> dict[str, object]:
    """Fabric, pressure (counts), speed (mm/s, signed) and repetition from a file name.

    Raises
    ------
    RecordingError
        When the name does not follow ``<Fabric>_F<pressure>_V<speed>mmps_<rep>.csv``
        or the speed is zero.
    """
    name = Path(path).name
    m = _NAME.match(name)
    if m is None:
        raise RecordingError(
            "file name does not follow <Fabric>_F<pressure>_V<speed>mmps_<rep>.csv "
            "(e.g. Linen_F180_V-10mmps_0.csv)",
            path=path,
        )
    speed = int(m["speed"])
    if speed == 0:
        raise RecordingError("sliding speed 0 mm/s in the file name", path=path)
    return {
        "fabric": m["fabric"],
        "pressure": int(m["pressure"]),
        "speed": speed,
        "direction": "down" if speed < 0 else "up",
        "repetition": int(m["rep"]),
        "condition": f"F{int(m['pressure'])}_V{speed}",
    }


def _read_table(path: Path) -> pd.DataFrame:
    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise RecordingError("the file is empty", path=path) from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise RecordingError(f"cannot read CSV: {exc}", path=path) from None
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise RecordingError(
            f"missing column(s) {missing}; expected header {', '.join(COLUMNS)}", path=path
        )
    df = df[list(COLUMNS)]
    for col in COLUMNS:
        values = pd.to_numeric(df[col], errors="coerce")
        bad = values.isna() | ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad.to_numpy()))
            cell = df[col].iloc[row]
            what = (f"non-numeric value {cell.strip()!r}" if isinstance(cell, str) and cell.strip()
                    else "missing value (a row cut short?)")
            raise RecordingError(f"{what} at data row {row + 1}", path=path, channel=col)
        df[col] = values.astype(np.float64)
    if len(df) < MIN_ROWS:
        raise RecordingError(f"only {len(df)} rows; a slide has at least {MIN_ROWS}", path=path)
    return df


def _drop_repeated_rows(df: pd.DataFrame, path: Path) -> tuple[pd.DataFrame, list[Problem]]:
    """Drop exact copies of the previous row; any other non-increasing timestamp is an error."""
    values = df.to_numpy()
    repeat = np.r_[False, np.all(values[1:] == values[:-1], axis=1)]
    problems = []
    if repeat.any():
        problems.append(Problem("duplicate_row", f"{int(repeat.sum())} repeated row(s) dropped"))
        df = df.loc[~repeat].reset_index(drop=True)
    ts = df["timestamp"].to_numpy()
    step = np.diff(ts)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0))
        raise RecordingError(
            f"timestamp not increasing at data row {i + 2} "
            f"({ts[i]:.0f} ms then {ts[i + 1]:.0f} ms)",
            path=path, channel="timestamp",
        )
    return df, problems


def read_slide(path: PathType) -> Recording:
    """Read one FabricSlide file into a :class:`Recording` (times in s from the first sample).

    Raises
    ------
    RecordingError
        Naming the file (and column) when the name, header, values or timestamps are malformed.
    """
    path = Path(path)
    meta = parse_name(path)
    df, problems = _drop_repeated_rows(_read_table(path), path)
    ts = df["timestamp"].to_numpy()
    t = (ts - ts[0]) / 1000.0
    rate = (len(t) - 1) / t[-1]
    samples = df[[*TAXELS, *PROXIMITY]].to_numpy()
    speed = abs(int(meta["speed"]))
    meta.update(
        label=meta["fabric"],
        ramp_s=RAMP_SPEED_TIME_MM / speed,
        logger_start_ms=float(ts[0]),
        dataset="fabricslide",
    )
    expected = slide_duration_s(speed)
    if t[-1] < SHORTEST_SHARE * expected:
        problems.append(Problem("truncated", f"the slide ends after {t[-1]:.1f} s; at {speed} "
                                f"mm/s it lasts {expected:.1f} s (file cut short?)"))
    channels = tuple(Channel(c, "counts") for c in (*TAXELS, *PROXIMITY))
    return Recording(t, samples, float(rate), channels, metadata=meta, name=path.stem,
                     problems=tuple(problems))


def slide_duration_s(speed_mm_s: float) -> float:
    """How long a slide at ``|speed_mm_s|`` lasts (s): two ramps and the steady travel."""
    return (2 * RAMP_SPEED_TIME_MM + STEADY_TRAVEL_MM) / abs(speed_mm_s)


def load(path: PathType, strict: bool = False) -> list[Recording]:
    """Read a FabricSlide folder (any subset of its files) or one file, sorted by name.

    Parameters
    ----------
    path : str or Path
        A folder of ``*.csv`` slides, or a single slide file.
    strict : bool, default False
        A malformed file, or a slide whose problems make its numbers wrong (e.g. cut
        short), raises. By default it is left out with a
        :class:`~frictionfit.recording.DatasetWarning` naming the file and the problem,
        and the others are still read.

    Raises
    ------
    DatasetError
        When the path is missing or holds no CSV file (or every file was skipped).
    RecordingError
        For a malformed or unusable file, with ``strict=True``.
    """
    root = Path(path)
    if root.is_file():
        files = [root]
    elif root.is_dir():
        files = sorted(root.glob("*.csv"))
    else:
        raise DatasetError(f"{root}: no such FabricSlide folder or file")
    if not files:
        raise DatasetError(f"{root}: no FabricSlide recordings (*.csv) in this folder")
    out = []
    for file in files:
        try:
            rec = read_slide(file)
        except RecordingError as exc:
            if strict:
                raise
            warnings.warn(f"skipped {exc}", DatasetWarning, stacklevel=2)
            continue
        if rec.disqualified:
            if strict:
                raise RecordingError(str(rec.disqualified[0]), path=file)
            warnings.warn(f"skipped {file}: {rec.disqualified[0]}", DatasetWarning, stacklevel=2)
            continue
        out.append(rec)
    if not out:
        raise DatasetError(f"{root}: every FabricSlide file was malformed and skipped")
    return out
