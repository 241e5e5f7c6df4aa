"""Write a recording while it happens, so a crash loses at most the last second.

:class:`RecordingWriter` writes the interchange format incrementally: the
sidecar first (``acquisition.status = "recording"``), CSV rows appended and
flushed to disk (``fsync``) every ``flush_s`` seconds, the sidecar rewritten
atomically at each flush and finalised last. :func:`record` runs the loop that
polls one or more :class:`~frictionfit.acquisition.stream.SensorStream` and
merges their samples into rows on a common grid.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from frictionfit.acquisition.stream import SensorStream
from frictionfit.errors import AcquisitionError
from frictionfit.recording import Channel, Event, Recording, recording_paths

__all__ = ["RecordingWriter", "record"]

#: Data reaches the disk at least this often (s): a crash loses at most this much.
FLUSH_S = 0.25


class RecordingWriter:
    """Append rows to ``<path>.csv`` and keep ``<path>.json`` current.

    Parameters
    ----------
    path : str or Path
        The stem (``.csv``/``.json`` are added).
    channels : sequence of Channel
        The columns after ``t``.
    sample_rate_hz : float
        Nominal rate (Hz) for the sidecar.
    metadata : dict, optional
        Free key/values for the sidecar's ``metadata``.
    overwrite : bool, default False
        Replace an existing recording at ``path``; without it :meth:`start` refuses to
        touch files that hold data.
    """

    def __init__(self, path: str | Path, channels: Sequence[Channel], sample_rate_hz: float,
                 metadata: dict[str, Any] | None = None, overwrite: bool = False) -> None:
        self.csv_path, self.json_path = recording_paths(path)
        self.channels = tuple(channels)
        self.sample_rate_hz = float(sample_rate_hz)
        self.metadata = dict(metadata or {})
        self.events: list[Event] = []
        self.rows_written = 0
        self.overwrite = overwrite
        self._lines: list[str] = []
        self._lock = threading.Lock()
        self._sidecar_lock = threading.Lock()
        self._acquisition: dict[str, Any] = {"status": "recording"}
        self._attached: dict[str, Callable[[], Any]] = {}
        self._csv = None
        self._started = False  # events added before start() are written by it

    def start(self) -> None:
        """Write the sidecar (with the events added so far), then the CSV header; both reach
        the disk. An existing recording is refused (:func:`refuse_existing`) unless
        ``overwrite``."""
        if not self.overwrite:
            refuse_existing(self.csv_path)
        with self._disk(self.csv_path.parent, "make the folder"):
            self.csv_path.parent.mkdir(parents=True, exist_ok=True)
        with self._lock:  # an event added from now on writes the sidecar itself
            self._started = True
        self._write_sidecar({"status": "recording"})
        with self._disk(self.csv_path, "write"):
            self._csv = open(self.csv_path, "w", encoding="ascii")  # noqa: SIM115 (kept open)
            try:
                self._csv.write(",".join(["t", *(c.name for c in self.channels)]) + "\n")
                self._sync()
            except OSError:
                self._close_csv()
                raise

    @contextlib.contextmanager
    def _disk(self, path: Path, what: str) -> Iterator[None]:
        """Turn a failed file operation into an :class:`AcquisitionError` naming the file,
        the reason and what is on disk so far."""
        try:
            yield
        except OSError as exc:
            raise AcquisitionError(
                f"{path}: cannot {what} ({exc.strerror or exc}); {self.rows_written} rows "
                f"are on disk, {len(self._lines)} received rows are not") from None

    def append(self, k: np.ndarray, values: np.ndarray) -> None:
        """Queue rows: grid indices ``k`` (n,) (t = k / rate) and values (n, n_channels)."""
        t = np.asarray(k) / self.sample_rate_hz
        lines = [f"{ti:.6f}," + ",".join(f"{v:.7g}" for v in row)
                 for ti, row in zip(t, np.asarray(values), strict=True)]
        with self._lock:
            self._lines += lines

    def add_event(self, event: Event) -> None:
        """Record a command (e.g. ``Event(t, "move", "p2")``); once :meth:`start` has run, the
        sidecar is rewritten at once, so a crash never loses an event that was sent (before,
        :meth:`start` writes it)."""
        with self._lock:
            self.events.append(event)
            started = self._started
        if started:
            self._write_sidecar(self._acquisition)

    def attach(self, key: str, snapshot: Callable[[], Any]) -> None:
        """Keep ``key`` in the sidecar as ``snapshot()`` returns it at every sidecar write
        (each flush and event), so it reaches the disk as often as the rows."""
        self._attached[key] = snapshot

    def write_rows(self) -> None:
        """Append the queued rows to the CSV and push them to the disk (fsync)."""
        if self._csv is None:
            raise AcquisitionError(f"{self.csv_path}: start() the writer before writing rows")
        with self._lock:
            lines = self._lines[:]
        with self._disk(self.csv_path, "write the rows"):
            if lines:
                self._csv.write("\n".join(lines) + "\n")
            self._sync()
        with self._lock:  # on disk: only now are they forgotten
            del self._lines[:len(lines)]
            self.rows_written += len(lines)

    def flush(self, acquisition: dict[str, Any]) -> None:
        """Write the queued rows, then rewrite the sidecar with ``acquisition``."""
        self.write_rows()
        self._write_sidecar(acquisition)

    def close(self, acquisition: dict[str, Any]) -> None:
        """Last flush with the final ``acquisition``; the CSV is closed. The sidecar is
        written even when the rows cannot be (its ``rows`` says how many are on disk)."""
        try:
            self.write_rows()
        finally:
            try:
                self._write_sidecar(acquisition)
            finally:
                self._close_csv()

    def _close_csv(self) -> None:
        if self._csv is not None:
            with contextlib.suppress(OSError):  # a write's error is the one raised
                self._csv.close()
            self._csv = None

    def _sync(self) -> None:
        assert self._csv is not None
        self._csv.flush()
        os.fsync(self._csv.fileno())

    def _write_sidecar(self, acquisition: dict[str, Any]) -> None:
        with self._sidecar_lock:  # the protocol's thread adds events while rows are flushed
            self._acquisition = acquisition
            with self._lock:
                events = tuple(self.events)
            attached = {key: snapshot() for key, snapshot in self._attached.items()}
            empty = Recording(np.empty(0), np.empty((0, len(self.channels))),
                              self.sample_rate_hz, self.channels, events=events,
                              metadata=self.metadata,
                              extra={"acquisition": acquisition, **attached})
            tmp = self.json_path.with_suffix(".json.tmp")
            with self._disk(self.json_path, "write the sidecar"):
                with open(tmp, "w", encoding="utf-8") as fh:
                    json.dump(empty.sidecar(), fh, indent=1)
                    fh.flush()
                    os.fsync(fh.fileno())
                os.replace(tmp, self.json_path)


def refuse_existing(path: str | Path) -> None:
    """:class:`~frictionfit.errors.AcquisitionError` if a recording at ``path`` (stem,
    ``.csv`` or ``.json``) already holds data, naming the file and how many rows it has."""
    for file in recording_paths(path):
        if file.exists() and file.stat().st_size > 0:
            rows = ""
            if file.suffix == ".csv":
                with open(file, "rb") as fh:
                    rows = f" ({max(sum(1 for _ in fh) - 1, 0)} rows)"
            raise AcquisitionError(f"{file} already exists{rows}; choose another --out or "
                                   "pass --overwrite to replace it")


class _Merger:
    """Rows on the common grid from several sensors; a missing sensor sample is NaN."""

    def __init__(self, widths: Sequence[int]) -> None:
        self.offsets = np.cumsum([0, *widths])
        self.rows: dict[int, np.ndarray] = {}
        self.next_k = 0  # the first grid index not yet handed out as a row

    def add(self, i: int, ks: np.ndarray, values: np.ndarray) -> None:
        lo, hi = self.offsets[i], self.offsets[i + 1]
        for k, v in zip(ks.tolist(), values, strict=True):
            row = self.rows.get(k)
            if row is None:
                row = self.rows[k] = np.full(self.offsets[-1], np.nan)
            row[lo:hi] = v

    def ready(self, horizon: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows with ``k < horizon``, in order, removed from the merger."""
        ks = sorted(k for k in self.rows if k < horizon)
        values = np.array([self.rows.pop(k) for k in ks]).reshape(len(ks), self.offsets[-1])
        if ks:
            self.next_k = ks[-1] + 1
        return np.asarray(ks, dtype=np.int64), values


def _summary(streams: Sequence[SensorStream], writer: RecordingWriter, status: str,
             started: float) -> dict[str, Any]:
    parts = [s.summary() for s in streams]
    total = {key: sum(p[key] for p in parts)
             for key in ("frames_valid", "frames_corrupted", "samples_lost")}
    span = max((p["frames_valid"] / p["rate_hz_achieved"] for p in parts
                if p["rate_hz_achieved"]), default=0.0)
    serials = [p["sensor_serial"] for p in parts]
    return {
        "status": status,
        "started_unix_s": round(started, 3),
        "rows": writer.rows_written,
        **total,
        "rate_hz_achieved": round(writer.rows_written / span, 3) if span else 0.0,
        "sensor_serial": serials[0] if len(serials) == 1 else serials,
        "gaps": [dict(g, sensor=p["name"]) for p in parts for g in p["gaps"]],
        "overloads": [o for p in parts for o in p["overloads"]],
        "sensors": [{k: v for k, v in p.items() if k not in ("gaps", "overloads")}
                    for p in parts],
    }


def record(
    streams: Sequence[SensorStream],
    out: str | Path,
    *,
    duration_s: float | None,
    stop: threading.Event | None = None,
    metadata: dict[str, Any] | None = None,
    on_start: Callable[[float, RecordingWriter], Callable[[], None]] | None = None,
    on_progress: Callable[[dict[str, Any]], None] | None = None,
    flush_s: float = FLUSH_S,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Record connected streams into ``out`` (.csv + .json) until ``duration_s`` or ``stop``.

    Parameters
    ----------
    streams : sequence of SensorStream
        Connected (``connect()`` done); all at the same rate.
    out : path
        The recording's stem.
    duration_s : float or None
        Seconds of host time to record; None runs until ``stop`` is set.
    stop : threading.Event, optional
        Set it (e.g. from a SIGINT/SIGTERM handler) to end cleanly.
    on_start : callable, optional
        Called once as ``stop = on_start(t0, writer)`` when the recording starts, with
        ``t0`` the host time (``time.monotonic()``) of sample 0, before the files' first
        writes (an event it adds meanwhile is written with the sidecar); ``stop()`` is
        called at the end. The rubbing protocol starts its command thread here, so a slow
        disk does not delay its first command.
    on_progress : callable, optional
        Called after every flush with the current ``acquisition`` summary.
    overwrite : bool, default False
        Replace an existing recording at ``out`` (refused otherwise, before any sensor
        is read).

    Returns
    -------
    dict
        The final ``acquisition`` object, as written to the sidecar.
    """
    stop = stop or threading.Event()
    if not overwrite:
        refuse_existing(out)
    rate, t0 = _first_frames(streams)
    writer = RecordingWriter(out, [c for s in streams for c in s.channels], rate,
                             {**(metadata or {}), "ports": [s.url for s in streams]},
                             overwrite=overwrite)
    merger = _Merger([len(s.channels) for s in streams])
    started = time.time()
    # the protocol first: its schedule runs from the first frame (t0), and the files' first
    # writes reach the disk (fsync) in their own time, which a busy disk makes long
    stop_hook = on_start(t0, writer) if on_start is not None else None
    _start_writing(streams, writer, stop_hook)
    status, failure = "interrupted", None
    try:
        status = _poll(streams, merger, writer, t0, started, stop, duration_s, flush_s,
                       on_progress)
    except AcquisitionError as exc:  # the disk refused the rows: the recording stops here
        status, failure = "failed", exc
    finally:
        if stop_hook is not None:
            stop_hook()
        summary, failure = _finish(streams, merger, writer, t0, started, status, failure)
    if failure is not None:
        raise AcquisitionError(f"{failure}; the recording stopped there")
    return summary


def _start_writing(streams: Sequence[SensorStream], writer: RecordingWriter,
                   stop_hook: Callable[[], None] | None) -> None:
    """Start ``writer``'s files; where the disk refuses, stop the protocol, close the streams,
    say so in the sidecar if it can still be written, and raise."""
    try:
        writer.start()
    except AcquisitionError as exc:
        if stop_hook is not None:
            stop_hook()
        for s in streams:
            s.close()
        with contextlib.suppress(AcquisitionError):  # say so where the sidecar can still go
            writer._write_sidecar({"status": "failed", "failure": str(exc)})
        raise


def _poll(streams: Sequence[SensorStream], merger: _Merger, writer: RecordingWriter,
          t0: float, started: float, stop: threading.Event, duration_s: float | None,
          flush_s: float, on_progress: Callable[[dict[str, Any]], None] | None) -> str:
    """Merge the streams' frames into ``writer``, flushing every ``flush_s``, until
    ``duration_s`` after ``t0`` ("complete") or ``stop`` ("interrupted")."""
    last_flush = time.monotonic()
    while not stop.is_set():
        _merge_polled(streams, merger, writer, t0)
        now = time.monotonic()
        if now - last_flush >= flush_s:
            _flush(streams, writer, started, on_progress)
            last_flush = now
        if duration_s is not None and now - t0 >= duration_s:
            return "complete"
        time.sleep(0.005)
    return "interrupted"


def _finish(streams: Sequence[SensorStream], merger: _Merger, writer: RecordingWriter,
            t0: float, started: float, status: str, failure: Exception | None
            ) -> tuple[dict[str, Any], Exception | None]:
    """Write what the streams still hold and close ``writer`` with the ``acquisition``
    summary; the summary and the failure that stopped the recording (None if none)."""
    _drain(streams, merger, writer, t0)
    try:
        writer.write_rows()
    except AcquisitionError as exc:  # the disk still refuses: its latest words
        status, failure = "failed", exc
    summary = _summary(streams, writer, status, started)
    if failure is not None:
        summary["failure"] = str(failure)
    try:
        writer.close(summary)
    except AcquisitionError as exc:
        failure = exc
    return summary, failure


def _first_frames(streams: Sequence[SensorStream]) -> tuple[float, float]:
    """The streams' common rate (Hz) and ``t0``, the host time of the earliest first frame,
    once every stream has sent one; a stream that sends none closes them all and raises."""
    rates = {s.rate_hz for s in streams}
    if len(rates) != 1:
        raise AcquisitionError(f"all sensors must run at one rate, got {sorted(rates)} Hz")
    try:
        for s in streams:
            s.wait_first_frame()
    except AcquisitionError:
        for s in streams:
            s.close()
        raise
    return rates.pop(), min(s.first_frame_time for s in streams)


def _merge_polled(streams: Sequence[SensorStream], merger: _Merger, writer: RecordingWriter,
                  t0: float) -> None:
    """Poll every stream and append the rows every connected stream has passed (one silent
    for :data:`~frictionfit.acquisition.stream.SILENT_S` holds back nothing)."""
    for i, s in enumerate(streams):
        merger.add(i, *s.poll(t0, merger.next_k))
    live = [s.last_k for s in streams if s.connected and not s.silent and s.last_k is not None]
    writer.append(*merger.ready(min(live) + 1 if live else np.inf))


def _flush(streams: Sequence[SensorStream], writer: RecordingWriter, started: float,
           on_progress: Callable[[dict[str, Any]], None] | None) -> None:
    """Write the rows so far and the sidecar's summary to disk; report progress."""
    writer.flush(_summary(streams, writer, "recording", started))
    if on_progress is not None:
        on_progress(_summary(streams, writer, "recording", started))


def _drain(streams: Sequence[SensorStream], merger: _Merger, writer: RecordingWriter,
           t0: float) -> None:
    """Close every stream, then merge what each had still buffered (written at close)."""
    for i, s in enumerate(streams):
        s.close()
        merger.add(i, *s.poll(t0, merger.next_k))
    writer.append(*merger.ready(np.inf))
