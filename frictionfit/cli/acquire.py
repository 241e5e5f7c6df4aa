"""``frictionfit acquire`` (record OptoForce sensors) and ``frictionfit rub`` (rubbing protocol)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer


def _open_streams(ports: list[str], names: list[str] | None, rate: float, filter_code: int,
                  zero: bool, sensitivity: Path | None) -> list[Any]:
    from frictionfit.acquisition.stream import SensorStream

    names = names or [f"s{i + 1}" for i in range(len(ports))]
    if len(names) != len(ports):
        typer.echo(f"error: {len(names)} --name for {len(ports)} ports", err=True)
        raise typer.Exit(2)
    streams = []
    for port, name in zip(ports, names, strict=True):
        stream = SensorStream(port, name, rate, filter_code=filter_code, zero=zero,
                              sensitivity=sensitivity)
        stream.connect()
        streams.append(stream)
    return streams


def _progress(quiet: bool, duration: float | None):
    import sys

    def show(acq: dict[str, Any]) -> None:
        sensors = acq["sensors"]
        t = max(s["frames_valid"] / s["rate_hz_achieved"] if s["rate_hz_achieved"] else 0.0
                for s in sensors)
        total = f"/{duration:g}" if duration else ""
        down = [s["name"] for s in sensors if not s["connected"]]
        sys.stderr.write(
            f"\r{t:7.1f}{total} s  rows {acq['rows']}  {acq['rate_hz_achieved']:.0f} Hz  "
            f"corrupted {acq['frames_corrupted']}  lost {acq['samples_lost']}"
            + (f"  DISCONNECTED {','.join(down)}" if down else "") + "   ")
        sys.stderr.flush()

    return None if quiet else show


def _run(streams: list[Any], out: Path, duration: float | None, quiet: bool,
         metadata: dict[str, Any], on_tick: Any = None) -> dict[str, Any]:
    """Record with SIGINT/SIGTERM ending the recording cleanly; print the summary."""
    import signal
    import threading

    from frictionfit.acquisition.recorder import record

    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        acq = record(streams, out, duration_s=duration, stop=stop, metadata=metadata,
                     on_tick=on_tick, on_progress=_progress(quiet, duration))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if not quiet:
        typer.echo("", err=True)
    typer.echo(
        f"{out}: {acq['rows']} rows, {acq['status']}; frames valid {acq['frames_valid']}, "
        f"corrupted {acq['frames_corrupted']}, samples lost {acq['samples_lost']} "
        f"in {len(acq['gaps'])} gap(s); achieved {acq['rate_hz_achieved']:g} Hz; "
        f"sensor {acq['sensor_serial']}")
    return acq


_PORT_HELP = "Sensor port: a device, a pty, loop:// or socket://host:port (repeat for more)."
_NAME_HELP = "Channel prefix per port (default s1, s2, ...): columns <name>_x, <name>_y, ..."
_SENS_HELP = "JSON file: serial number -> counts per N per axis. Without it: raw counts."


def acquire(
    port: list[str] = typer.Option(..., "--port", help=_PORT_HELP),
    out: Path = typer.Option(..., "--out", help="Stem of the recording: NAME.csv + NAME.json."),
    rate: float = typer.Option(1000.0, help="Sample rate in Hz: 1000, 333, 100, 30 or 10."),
    duration: float = typer.Option(0.0, help="Seconds to record; 0 = until Ctrl-C."),
    name: list[str] = typer.Option(None, "--name", help=_NAME_HELP),
    sensitivity: Path = typer.Option(None, help=_SENS_HELP),
    filter_code: int = typer.Option(0, "--filter", help="DAQ low-pass: 0 none, 1 500 Hz, "
                                    "2 150, 3 50, 4 15, 5 5, 6 1.5 Hz."),
    zero: bool = typer.Option(False, help="Tare the sensors in the DAQ at start."),
    quiet: bool = typer.Option(False, help="No live progress line."),
) -> None:
    """Record OptoForce sensors losslessly into the interchange format.

    Data reach the disk every 0.25 s, so a crash or a pulled cable loses at most
    that; the port is reopened when it comes back, and the gap is listed in the
    sidecar's ``acquisition`` object. Ctrl-C or SIGTERM end the recording cleanly.
    """
    from frictionfit.errors import AcquisitionError

    try:
        streams = _open_streams(port, name, rate, filter_code, zero, sensitivity)
        _run(streams, out, duration or None, quiet, {})
    except AcquisitionError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None


def rub() -> None:
    """Not written yet."""
    raise typer.Exit(2)
