"""Touch gestures on a textile pressure-matrix skin (e.g. 20 x 20 taxels, 1 cm pitch, 50 frames/s).

A gesture folder holds one recording per gesture, either

- in the interchange format (``<name>.csv`` + ``<name>.json``) with one channel per
  taxel named ``r{row}c{col}`` (unit ``"kPa"`` or ``"1"``), or
- as ``<name>.npz`` with ``frames`` (time x rows x cols), ``rate_hz``, ``label`` and
  ``person``; optional ``repetition``, ``gesture``, ``unit`` and ``metadata`` /
  ``truth`` (JSON strings).

Every recording comes back with ``samples`` of shape (time, rows * cols) in row-major
taxel order and ``metadata`` carrying ``label``, ``person``, ``repetition`` and
``gesture`` (``gesture`` defaults to ``label``; a missing ``repetition`` is the
recording's ordinal among the same person's same gesture, in file-name order).
"""

from __future__ import annotations

import json
import re
import warnings
import zipfile
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from frictionfit._types import PathType
from frictionfit.errors import DatasetError, RecordingError
from frictionfit.recording import DatasetWarning, Recording, read_recording, validate

__all__ = ["GESTURE_UNITS", "frames_of", "load", "recording_from_frames", "taxel_names"]

#: Units a taxel channel may carry: pressure in kPa, or a normalised reading.
GESTURE_UNITS = frozenset({"kPa", "1"})
_TAXEL = re.compile(r"^r(\d+)c(\d+)$")
#: Validation findings that are normal for a pressure matrix: untouched taxels are constant.
_EXPECTED = frozenset({"dead_channel", "gap"})


def taxel_names(rows: int, cols: int) -> list[str]:
    """Channel names ``r{row}c{col}`` of a ``rows x cols`` matrix, row-major."""
    return [f"r{r}c{c}" for r in range(rows) for c in range(cols)]


def recording_from_frames(
    frames: np.ndarray,
    rate_hz: float,
    metadata: dict[str, Any],
    *,
    unit: str = "kPa",
    name: str = "gesture",
    truth: dict[str, Any] | None = None,
) -> Recording:
    """A :class:`Recording` of pressure frames (time x rows x cols, in ``unit``) at ``rate_hz``."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 3:
        raise RecordingError(
            f"frames must be 3-D (time x rows x cols), got shape {frames.shape}", path=name
        )
    n, rows, cols = frames.shape
    return Recording.from_arrays(
        frames.reshape(n, rows * cols),
        float(rate_hz),
        taxel_names(rows, cols),
        units=unit,
        metadata=dict(metadata),
        truth=dict(truth or {}),
        name=name,
    )


def _grid(rec: Recording) -> tuple[int, int, np.ndarray]:
    """Rows, cols and the column index of each row-major taxel; raises naming the channel."""
    pos = []
    for ch in rec.channels:
        m = _TAXEL.match(ch.name)
        if m is None:
            raise RecordingError(
                "channel name is not a taxel name r{row}c{col}", path=rec.name, channel=ch.name
            )
        if ch.unit not in GESTURE_UNITS:
            raise RecordingError(
                f"unit {ch.unit!r} is not a taxel unit; expected one of {sorted(GESTURE_UNITS)}",
                path=rec.name,
                channel=ch.name,
            )
        pos.append((int(m.group(1)), int(m.group(2))))
    if not pos:
        raise RecordingError("no taxel channels", path=rec.name)
    rows = max(r for r, _ in pos) + 1
    cols = max(c for _, c in pos) + 1
    index = np.full(rows * cols, -1)
    for j, (r, c) in enumerate(pos):
        if index[r * cols + c] >= 0:
            raise RecordingError("taxel appears twice", path=rec.name, channel=f"r{r}c{c}")
        index[r * cols + c] = j
    if (index < 0).any():
        k = int(np.argmax(index < 0))
        raise RecordingError(
            f"taxel matrix {rows} x {cols} is incomplete: {int((index < 0).sum())} taxel(s) "
            f"missing, first r{k // cols}c{k % cols}",
            path=rec.name,
        )
    return rows, cols, index


def frames_of(rec: Recording) -> np.ndarray:
    """The pressure frames of a gesture recording, shape (time, rows, cols), float64."""
    rows, cols, index = _grid(rec)
    samples = rec.samples
    if not np.array_equal(index, np.arange(index.size)):
        samples = samples[:, index]
    return samples.reshape(rec.n_samples, rows, cols)


def _scalar(data: Any, key: str, path: Path) -> Any:
    value = data[key]
    if value.ndim != 0:
        raise RecordingError(
            f"npz entry {key!r} must be a scalar, got shape {value.shape}", path=path
        )
    return value.item()


def _json_entry(data: Any, key: str, path: Path) -> dict[str, Any]:
    if key not in data:
        return {}
    try:
        out = json.loads(str(_scalar(data, key, path)))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"npz entry {key!r} is not valid JSON: {exc}", path=path) from None
    if not isinstance(out, dict):
        raise RecordingError(f"npz entry {key!r} must hold a JSON object", path=path)
    return out


def _read_npz(path: Path) -> Recording:
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ("frames", "rate_hz", "label", "person") if k not in data]
            if missing:
                raise RecordingError(
                    f"npz lacks {missing}; a gesture needs frames, rate_hz, label, person",
                    path=path,
                )
            frames = np.asarray(data["frames"])
            if frames.ndim != 3 or min(frames.shape) < 1:
                raise RecordingError(
                    f"'frames' must be time x rows x cols, got shape {frames.shape}", path=path
                )
            if not np.issubdtype(frames.dtype, np.number):
                raise RecordingError(f"'frames' must be numeric, not {frames.dtype}", path=path)
            rate = float(_scalar(data, "rate_hz", path))
            metadata = _json_entry(data, "metadata", path)
            truth = _json_entry(data, "truth", path)
            for key in ("label", "person", "repetition", "gesture"):
                if key in data:
                    metadata[key] = _scalar(data, key, path)
            unit = str(_scalar(data, "unit", path)) if "unit" in data else "kPa"
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, RecordingError):
            raise
        # an empty file raises EOFError, which a command line would take for Ctrl-D
        raise RecordingError(f"cannot read npz: {exc or type(exc).__name__}",
                             path=path) from None
    if not np.isfinite(rate) or rate <= 0:
        raise RecordingError(f"rate_hz must be a positive number, got {rate}", path=path)
    if unit not in GESTURE_UNITS:
        raise RecordingError(
            f"unit {unit!r} is not a taxel unit; expected one of {sorted(GESTURE_UNITS)}", path=path
        )
    return recording_from_frames(frames, rate, metadata, unit=unit, name=path.stem, truth=truth)


def _read_one(path: Path) -> Recording:
    if path.suffix == ".npz":
        rec = _read_npz(path)
    else:
        rec = read_recording(path, on_error="flag")
    try:
        _grid(rec)
    except RecordingError as exc:
        raise RecordingError(exc.problem, path=path, channel=exc.channel) from None
    found = validate(rec) if path.suffix == ".npz" else rec.problems
    problems = [p for p in found if p.kind not in _EXPECTED]
    for key in ("label", "person"):
        if rec.metadata.get(key) in (None, ""):
            raise RecordingError(f"metadata lacks {key!r} (a gesture needs label and person)",
                                 path=path)
    rec.metadata.setdefault("gesture", rec.metadata["label"])
    return rec.with_problems(problems)


def load(path: PathType, strict: bool = False) -> list[Recording]:
    """Read a folder of gesture recordings (interchange format and/or ``.npz``), by file name.

    Parameters
    ----------
    path : str or PathLike
        The folder.

    Returns
    -------
    list of Recording
        One per gesture; ``samples`` are taxel pressures (time, rows * cols) in kPa (or
        normalised, unit ``"1"``); ``metadata`` has ``label``, ``person``, ``repetition``,
        ``gesture``. Validation findings other than constant (untouched) taxels are kept in
        ``problems``, so NaN frames are flagged rather than hidden.

    Raises
    ------
    DatasetError
        The folder is missing or empty, or recordings disagree on the taxel matrix.
    RecordingError
        With ``strict``, a file is malformed (names the file, and the channel where one is
        at fault); by default it is left out with a
        :class:`~frictionfit.recording.DatasetWarning`.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder of gesture recordings")
    paths = sorted([*folder.glob("*.csv"), *folder.glob("*.npz")], key=lambda p: p.name)
    if not paths:
        raise DatasetError(f"{folder}: no gesture recordings (<name>.csv + .json, or <name>.npz)")
    read = []
    for p in paths:
        try:
            read.append((p, _read_one(p)))
        except RecordingError as exc:
            if strict:
                raise
            warnings.warn(f"skipped {exc}", DatasetWarning, stacklevel=2)
    if not read:
        raise DatasetError(f"{folder}: none of its {len(paths)} gesture recordings could be read")
    paths, recs = [p for p, _ in read], [r for _, r in read]
    shape = _grid(recs[0])[:2]
    seen: Counter[tuple[str, str]] = Counter()
    for p, rec in zip(paths, recs, strict=True):
        if _grid(rec)[:2] != shape:
            raise DatasetError(
                f"{p}: taxel matrix {_grid(rec)[:2]} differs from {shape} of {paths[0].name}"
            )
        key = (str(rec.metadata["person"]), str(rec.metadata["gesture"]))
        rec.metadata.setdefault("repetition", seen[key])
        seen[key] += 1
    return recs
