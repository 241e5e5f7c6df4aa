"""``frictionfit acquire`` (record OptoForce sensors) and ``frictionfit rub`` (rubbing protocol)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer


def _check_out(out: Path, overwrite: bool) -> None:
    """Refuse, before any port is opened, an ``--out`` that holds a recording (unless
    ``overwrite``) or where none can be written."""
    from frictionfit.acquisition.recorder import refuse_existing
    from frictionfit.cli._load import check_writable, make_folder
    from frictionfit.recording import recording_paths

    if not overwrite:
        refuse_existing(out)
    make_folder(out.parent, "--out")
    for path in recording_paths(out):
        check_writable(path, "--out")


def _open_streams(ports: list[str], names: list[str] | None, rate: float, filter_code: int,
                  zero: bool, sensitivity: Path | None) -> list[Any]:
    from frictionfit.acquisition.stream import SensorStream
    from frictionfit.recording import check_channel_names

    names = names or [f"s{i + 1}" for i in range(len(ports))]
    if len(names) != len(ports):
        raise typer.BadParameter(f"{len(names)} --name for {len(ports)} ports",
                                 param_hint="--name")
    try:
        check_channel_names(names)  # unique, CSV-safe prefixes make unique, CSV-safe columns
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--name") from None
    streams = [SensorStream(port, name, rate, filter_code=filter_code, zero=zero,
                            sensitivity=sensitivity) for port, name in zip(ports, names,
                                                                           strict=True)]
    try:
        for stream in streams:
            stream.connect()
    except Exception:
        for stream in streams:
            stream.close()
        raise
    return streams


def _progress(quiet: bool, duration: float | None):
    import sys

    def show(acq: dict[str, Any]) -> None:
        sensors = acq["sensors"]
        t = max(s["frames_valid"] / s["rate_hz_achieved"] if s["rate_hz_achieved"] else 0.0
                for s in sensors)
        total = f"/{duration:g}" if duration else ""
        down = [s["name"] for s in sensors if not s["connected"]]
        silent = [s["name"] for s in sensors if s["silent"]]
        sys.stderr.write(
            f"\r{t:7.1f}{total} s  rows {acq['rows']}  {acq['rate_hz_achieved']:.0f} Hz  "
            f"corrupted {acq['frames_corrupted']}  lost {acq['samples_lost']}"
            + (f"  DISCONNECTED {','.join(down)}" if down else "")
            + (f"  SILENT {','.join(silent)}" if silent else "") + "   ")
        sys.stderr.flush()

    return None if quiet else show


def _run(streams: list[Any], out: Path, duration: float | None, quiet: bool,
         metadata: dict[str, Any], on_start: Any = None, overwrite: bool = False
         ) -> dict[str, Any]:
    """Record with SIGINT/SIGTERM ending the recording cleanly; print the summary."""
    import signal
    import threading

    from frictionfit.acquisition.recorder import record

    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        acq = record(streams, out, duration_s=duration, stop=stop, metadata=metadata,
                     on_start=on_start, on_progress=_progress(quiet, duration),
                     overwrite=overwrite)
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
    overwrite: bool = typer.Option(False, help="Replace an existing recording at --out."),
) -> None:
    """Record OptoForce sensors losslessly into the interchange format.

    Data reach the disk every 0.25 s, so a crash loses at most that. A pulled cable
    loses what was in flight; the port is reopened when it comes back and the gap is
    listed in the sidecar's ``acquisition`` object, as is a sensor that falls silent
    (it holds back the others' rows 1 s at most) and a DAQ that restarts (it is
    configured again). A disk that refuses the rows stops the recording, saying how
    many are on it. Ctrl-C or SIGTERM end cleanly. `frictionfit info NAME` sums it up.
    """
    from frictionfit.errors import AcquisitionError

    if duration < 0:
        raise typer.BadParameter(f"must be >= 0 s (0: until Ctrl-C), got {duration:g}",
                                 param_hint="--duration")
    try:
        _check_out(out, overwrite)
        streams = _open_streams(port, name, rate, filter_code, zero, sensitivity)
        _run(streams, out, duration or None, quiet, {}, overwrite=overwrite)
    except AcquisitionError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None


def _actuator(spec: str, p1: float, p2: float, servo_id: int, baud: int) -> Any:
    """The drive, ready to move, with both positions checked against its limits."""
    from frictionfit.acquisition.actuator import DynamixelActuator, SimulatedGripper
    from frictionfit.errors import AcquisitionError

    if spec == "sim":
        return SimulatedGripper(p1)
    servo = DynamixelActuator(spec, servo_id, baudrate=baud)
    try:
        servo.prepare()
        for option, position in (("--p1", p1), ("--p2", p2)):
            try:
                servo.check(position)
            except AcquisitionError as exc:
                raise AcquisitionError(f"{option}: {exc}") from None
    except Exception:
        servo.close()
        raise
    return servo


def rub(
    sensor: list[str] = typer.Option(..., "--sensor", help=_PORT_HELP),
    actuator: str = typer.Option(..., help="Dynamixel servo port, or 'sim' for a simulated "
                                 "gripper."),
    p1: float = typer.Option(..., help="Closed (start) position, actuator units (counts)."),
    p2: float = typer.Option(..., help="Rubbing position, actuator units (counts)."),
    out: Path = typer.Option(..., "--out", help="Stem of the recording: NAME.csv + NAME.json."),
    motions: int = typer.Option(5, help="Number of rubbing motions (p1 -> p2 -> p1)."),
    dwell: float = typer.Option(1.0, help="Seconds between commands."),
    label: str = typer.Option(None, help="Material label for the sidecar's metadata."),
    rate: float = typer.Option(1000.0, help="Sample rate in Hz: 1000, 333, 100, 30 or 10."),
    name: list[str] = typer.Option(None, "--name", help=_NAME_HELP),
    sensitivity: Path = typer.Option(None, help=_SENS_HELP),
    servo_id: int = typer.Option(1, help="Dynamixel ID."),
    baud: int = typer.Option(57_600, help="Dynamixel baud rate."),
    position_rate: float = typer.Option(50.0, help="Reads per second of the motor's present "
                                        "position between commands; 0 = none."),
    quiet: bool = typer.Option(False, help="No live progress line."),
    overwrite: bool = typer.Option(False, help="Replace an existing recording at --out."),
) -> None:
    """Run the rubbing protocol while recording the forces, ready for ``frictionfit fit``.

    The finger goes to p1, then ``--motions`` times to p2 and back, a command every
    ``--dwell`` seconds from t = 0.05 s; each command is a ``move`` event in the sidecar.
    Between commands the motor's present position is read ``--position-rate`` times a
    second (as fast as the servo answers, at most) into the sidecar's
    ``motor_positions``; a failed read is counted and skipped.
    """
    from frictionfit.acquisition.protocol import ProtocolRunner, RubbingProtocol
    from frictionfit.errors import AcquisitionError

    try:
        protocol = RubbingProtocol(p1, p2, motions, dwell)
        if not position_rate >= 0:
            raise ValueError(f"--position-rate must be >= 0 Hz, got {position_rate:g}")
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    try:
        _check_out(out, overwrite)
        drive = _actuator(actuator, p1, p2, servo_id, baud)
        try:
            drive.move_to(p1)
            streams = _open_streams(sensor, name, rate, 0, False, sensitivity)
            meta = {"protocol": {"p1": p1, "p2": p2, "motions": motions, "dwell_s": dwell,
                                 "actuator": actuator}}
            if label is not None:
                meta["label"] = label
            runner = ProtocolRunner(protocol, drive, position_rate_hz=position_rate)
            _run(streams, out, protocol.duration_s, quiet, meta, runner.start, overwrite)
        finally:
            drive.close()
        if runner.positions is not None:
            typer.echo(runner.positions.summary())
        if runner.error is not None:
            raise AcquisitionError(f"{actuator}: {runner.error} (the recording is kept)")
    except AcquisitionError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
