"""The recorder: every valid frame kept, damage counted exactly, crash- and cable-safe.

A fake OptoForce DAQ on a pty (tests/fake_optoforce.py) streams at 1 kHz with frames
corrupted on purpose and garbage between frames.
"""

import errno
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from fake_optoforce import FakeOptoForce
from typer.testing import CliRunner

from frictionfit.acquisition import stream as stream_module
from frictionfit.acquisition.recorder import RecordingWriter, record
from frictionfit.acquisition.stream import SensorStream
from frictionfit.cli import app
from frictionfit.errors import AcquisitionError
from frictionfit.recording import Channel, Event, read_recording

CLI = [sys.executable, "-c", "import sys; from frictionfit.cli import main; main()"]


def _acquire_exactly(tmp_path, seconds):
    out = tmp_path / "rec"
    with FakeOptoForce(tmp_path / "tty", corrupt_every=97, garbage_every=31) as fake:
        result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                          "--duration", str(seconds), "--out", str(out)])
    assert result.exit_code == 0, result.output
    rec = read_recording(out, on_error="flag")
    acq = rec.extra["acquisition"]
    assert fake.frames_corrupted >= seconds * 1000 // 97 - 2
    # every valid frame is in the file, and the damage is reported exactly
    assert rec.n_samples == fake.frames_sent - fake.frames_corrupted
    assert acq["frames_corrupted"] == fake.frames_corrupted
    assert acq["frames_valid"] == rec.n_samples == acq["rows"]
    assert acq["samples_lost"] == fake.frames_corrupted == len(acq["gaps"])
    assert f"corrupted {fake.frames_corrupted}," in result.output
    assert acq["status"] == "complete" and acq["sensor_serial"] == "ISE0A129"
    assert [p.kind for p in rec.problems] == ["gap"]
    assert rec.channel_names == ("s1_x", "s1_y", "s1_z")
    return acq, fake


def test_acquire_keeps_every_valid_frame(tmp_path):
    acq, _ = _acquire_exactly(tmp_path, 5)
    assert 950 < acq["rate_hz_achieved"] <= 1000


@pytest.mark.slow
def test_acquire_60_s_keeps_every_valid_frame(tmp_path):
    acq, fake = _acquire_exactly(tmp_path, 60)
    print(f"60 s: sent {fake.frames_sent}, corrupted {fake.frames_corrupted}, "
          f"rate achieved {acq['rate_hz_achieved']} Hz")


def test_writer_sidecar_first_and_rows_readable_before_close(tmp_path):
    writer = RecordingWriter(tmp_path / "w", [Channel("a_x", "N")], 1000.0, {"label": "x"})
    writer.start()
    assert json.loads((tmp_path / "w.json").read_text())["acquisition"] == {
        "status": "recording"}
    writer.append(np.arange(5), np.arange(5.0)[:, None] / 3)
    writer.add_event(Event(0.002, "move", "p2"))
    writer.flush({"status": "recording", "rows": 5})
    rec = read_recording(tmp_path / "w")  # readable while still open
    assert rec.n_samples == 5 and rec.events == (Event(0.002, "move", "p2"),)
    np.testing.assert_allclose(rec.channel("a_x"), np.arange(5) / 3, rtol=1e-6)
    writer.close({"status": "complete"})
    assert read_recording(tmp_path / "w").extra["acquisition"]["status"] == "complete"


def test_an_event_reaches_the_sidecar_before_any_flush(tmp_path):
    writer = RecordingWriter(tmp_path / "w", [Channel("a_x", "N")], 1000.0)
    writer.start()
    writer.append(np.arange(3), np.zeros((3, 1)))
    writer.add_event(Event(0.05, "move", "p2"))  # then the process dies: no flush, no close
    side = json.loads((tmp_path / "w.json").read_text())
    writer._csv.close()  # what the dying process's OS does; no frictionfit code runs
    assert side["events"] == [{"t": 0.05, "kind": "move", "target": "p2"}]
    assert side["acquisition"] == {"status": "recording"}


def test_a_crash_after_a_command_leaves_a_readable_recording(tmp_path):
    writer = RecordingWriter(tmp_path / "run_1.5mm", [Channel("a_x", "N")], 1000.0)
    writer.start()
    writer.append(np.arange(100), np.arange(100.0)[:, None] / 7)
    writer.add_event(Event(0.05, "move", "p2"))
    writer.flush({"status": "recording", "rows": 100})
    writer.add_event(Event(0.2, "move", "p1"))  # sent; the process dies before its rows flush
    writer._csv.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run_1.5mm.csv", "run_1.5mm.json"]
    rec = read_recording(tmp_path / "run_1.5mm")  # every flushed row and sent command kept
    assert rec.n_samples == 100 and len(rec.events) == 2
    assert [p.kind for p in rec.problems] == ["ends_early"]


def test_attached_data_reach_the_sidecar_at_every_write(tmp_path):
    reads = [[0.01, 0.02, 5.0]]
    writer = RecordingWriter(tmp_path / "w", [Channel("a_x", "N")], 1000.0)
    writer.start()
    writer.attach("motor_positions", lambda: {"reads": list(reads)})
    writer.add_event(Event(0.05, "move", "p2"))  # then the process dies: no flush, no close
    assert json.loads((tmp_path / "w.json").read_text())["motor_positions"] == {
        "reads": [[0.01, 0.02, 5.0]]}
    reads.append([0.03, 0.04, 6.0])
    writer.close({"status": "complete"})
    assert read_recording(tmp_path / "w", on_error="flag").extra["motor_positions"] == {
        "reads": reads}


def test_an_existing_recording_is_never_overwritten_without_asking(tmp_path):
    with FakeOptoForce(tmp_path / "tty") as _:
        first = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                         "--duration", "0.5", "--out", str(tmp_path / "rec")])
    assert first.exit_code == 0, first.output
    before = (tmp_path / "rec.csv").read_bytes()
    rows = len(before.splitlines()) - 1
    again = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                     "--duration", "0.5", "--out", str(tmp_path / "rec")])
    assert again.exit_code == 1
    assert f"rec.csv already exists ({rows} rows); choose another --out or pass --overwrite" \
        in again.output
    assert (tmp_path / "rec.csv").read_bytes() == before
    writer = RecordingWriter(tmp_path / "rec", [Channel("a_x", "N")], 1000.0)
    with pytest.raises(AcquisitionError, match="rec.csv already exists"):
        writer.start()
    assert (tmp_path / "rec.csv").read_bytes() == before
    with FakeOptoForce(tmp_path / "tty") as _:
        forced = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                          "--duration", "0.5", "--out", str(tmp_path / "rec"),
                                          "--overwrite"])
    assert forced.exit_code == 0, forced.output


def test_pulled_cable_reconnects_with_the_gap_marked(tmp_path):
    with FakeOptoForce(tmp_path / "tty") as fake:
        stream = SensorStream(str(tmp_path / "tty"), "thumb", 1000)
        stream.connect()
        timer = threading.Timer(0.8, fake.disconnect)
        timer2 = threading.Timer(1.4, fake.reconnect)
        timer.start()
        timer2.start()
        acq = record([stream], tmp_path / "rec", duration_s=2.5)
        timer.join()
        timer2.join()
    rec = read_recording(tmp_path / "rec", on_error="flag")
    links = [g for g in acq["gaps"] if g["cause"].startswith("link lost")]
    assert len(links) == 1 and acq["sensors"][0]["reconnects"] == 1
    assert 0.7 < links[0]["t"] < 0.9 and 500 < links[0]["samples"] < 1300
    dt = np.diff(rec.t)
    assert np.isclose(dt.max(), (links[0]["samples"] + 1) / 1000)  # the hole is in t
    assert rec.t[-1] > 2.0 and [p.kind for p in rec.problems] == ["gap"]


def test_frames_received_before_the_cable_was_pulled_are_kept(tmp_path):
    with FakeOptoForce(tmp_path / "tty", source=lambda k: (k, 7, 9)) as fake:
        stream = SensorStream(str(tmp_path / "tty"), "thumb", 1000, retry_s=60)
        stream.connect()
        stream.wait_first_frame()
        t0 = stream.first_frame_time
        time.sleep(0.3)  # frames wait in the reader's queue, not yet polled
        fake.disconnect()
        deadline = time.monotonic() + 5
        while stream.sensor.alive and time.monotonic() < deadline:
            time.sleep(0.01)
        ks, values = stream.poll(t0)  # the link has ended: its frames are still numbered
        stream.close()
    assert not stream.connected and fake.frames_sent > 250
    # every frame the fake wrote before the pty closed (a few may die in the kernel's buffer)
    assert fake.frames_sent - 5 <= len(ks) <= fake.frames_sent
    np.testing.assert_array_equal(values[:, 0], np.arange(len(ks)))
    np.testing.assert_array_equal(ks, ks[0] + np.arange(len(ks)))


class _FullDisk:
    """The CSV's file once its disk has filled up: every write fails with ENOSPC."""

    def __init__(self, file):
        self.file = file

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self.file, name)


def test_a_full_disk_stops_the_recording_in_words_and_the_sidecar_says_so(tmp_path):
    def fill_the_disk_later(t0, writer):
        timer = threading.Timer(0.6, lambda: setattr(writer, "_csv", _FullDisk(writer._csv)))
        timer.start()
        return timer.cancel

    with FakeOptoForce(tmp_path / "tty") as fake:
        stream = SensorStream(str(tmp_path / "tty"), "thumb", 1000)
        stream.connect()
        started = time.monotonic()
        with pytest.raises(AcquisitionError, match=(
                r"rec.csv: cannot write the rows \(No space left on device\); \d+ rows are "
                r"on disk, \d+ received rows are not; the recording stopped there")):
            record([stream], tmp_path / "rec", duration_s=20, on_start=fill_the_disk_later)
    assert time.monotonic() - started < 10
    assert fake.configs[-1].speed == 0  # the DAQ was told to stop
    rec = read_recording(tmp_path / "rec", on_error="flag")
    acq = rec.extra["acquisition"]
    assert acq["status"] == "failed" and "No space left on device" in acq["failure"]
    assert acq["rows"] == rec.n_samples and 300 < rec.n_samples < 1000
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rec")])
    assert (f"acquisition: failed ({acq['failure']}): {rec.n_samples} rows in the CSV"
            in info.output)


def test_a_disk_that_refuses_the_first_row_is_said_before_any_sample(tmp_path):
    (tmp_path / "rec.csv").symlink_to("/dev/full")  # writes fail with ENOSPC
    with FakeOptoForce(tmp_path / "tty"):
        result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                          "--duration", "5", "--out", str(tmp_path / "rec")])
    assert result.exit_code == 1
    assert "rec.csv: cannot write (No space left on device); 0 rows are on disk" in result.output
    sidecar = json.loads((tmp_path / "rec.json").read_text())
    assert sidecar["acquisition"]["status"] == "failed"


def test_a_sensor_back_after_a_pulled_cable_never_writes_behind_the_others_rows(tmp_path):
    # b's clock runs 5 % fast: after 1.4 s its rows are ~70 samples ahead of the host's
    # clock, by which a's new link is placed
    with FakeOptoForce(tmp_path / "a") as fa, FakeOptoForce(tmp_path / "b", rate_error=0.05):
        streams = [SensorStream(str(tmp_path / n), n, 1000) for n in "ab"]
        for s in streams:
            s.connect()
        timers = [threading.Timer(0.8, fa.disconnect), threading.Timer(1.4, fa.reconnect)]
        for timer in timers:
            timer.start()
        acq = record(streams, tmp_path / "rec", duration_s=2.5)
        for timer in timers:
            timer.join()
    rec = read_recording(tmp_path / "rec", on_error="flag")
    assert acq["sensors"][0]["reconnects"] == 1
    assert np.all(np.diff(rec.t) > 0)  # every row once, in time order
    a_back = np.isfinite(rec.samples[:, 0]) & (rec.t > 1.2)
    assert a_back.sum() > 500  # a's samples after the reconnection are kept


def _two_sensors_with(tmp_path, fault, at_s=0.8, duration_s=3.0):
    """Record sensors a and b (a's Fx is its frame number, b's minus its own) while
    ``fault(fake_a)`` runs at ``at_s``; the acquisition summary and the recording."""
    with FakeOptoForce(tmp_path / "a", source=lambda k: (k % 30000, 7, 9)) as fa, \
            FakeOptoForce(tmp_path / "b", source=lambda k: (-(k % 30000), 5, 3)):
        streams = [SensorStream(str(tmp_path / n), n, 1000) for n in "ab"]
        for s in streams:
            s.connect()
        timer = threading.Timer(at_s, fault, (fa,))
        timer.start()
        acq = record(streams, tmp_path / "rec", duration_s=duration_s)
        timer.join()
    return acq, read_recording(tmp_path / "rec", on_error="flag")


def test_a_silent_sensor_holds_back_the_others_rows_one_second_at_most(tmp_path):
    rows = []

    def pause_and_watch(fake):
        csv = tmp_path / "rec.csv"
        watch = threading.Thread(target=lambda: [
            (rows.append(csv.read_text().count("\n")), time.sleep(0.1)) for _ in range(25)])
        watch.start()
        fake.pause(2.0)
        watch.join()

    acq, rec = _two_sensors_with(tmp_path, pause_and_watch, duration_s=4.0)
    # rows reach the disk again within ~1 s of the silence (SILENT_S), not after it
    stuck = max(sum(1 for _ in group) for _, group in itertools.groupby(rows))
    assert stuck <= 14, rows
    (gap,) = acq["gaps"]
    assert gap["sensor"] == "a" and "fell silent for 2" in gap["cause"]
    assert 1900 < gap["samples"] < 2100
    # a's frames after the silence are placed by their arrival, beside b's of that moment
    a, b = rec.samples[:, 0], rec.samples[:, 3]
    after = np.isfinite(a) & (rec.t > 3.0)
    assert after.sum() > 500
    lag = rec.t[after][0] - rec.t[np.flatnonzero(b == -a[after][0] - 2000)][0]
    assert abs(lag) < 0.05  # b's frame of the same moment: 2000 frames further on
    assert np.all(np.diff(rec.t) > 0)


def test_a_lone_sensor_silent_with_its_counter_keeps_its_time_line(tmp_path):
    with FakeOptoForce(tmp_path / "a", source=lambda k: (k % 30000, 7, 9)) as fake:
        stream = SensorStream(str(tmp_path / "a"), "a", 1000)
        stream.connect()
        timer = threading.Timer(0.8, fake.pause, (1.5,))
        timer.start()
        acq = record([stream], tmp_path / "rec", duration_s=3.5)
        timer.join()
    rec = read_recording(tmp_path / "rec", on_error="flag")
    (gap,) = acq["gaps"]
    assert "fell silent for 1.5" in gap["cause"] and 1400 < gap["samples"] < 1600
    frame = rec.samples[:, 0]
    before, after = rec.t < 0.7, rec.t > 2.5
    np.testing.assert_allclose(rec.t[before] - frame[before] / 1000, 0, atol=0.01)
    # frames sent after the silence are 1.5 s later than their numbers say
    np.testing.assert_allclose(rec.t[after] - frame[after] / 1000, 1.5, atol=0.05)


def test_a_counter_that_restarts_is_placed_by_the_host_clock(tmp_path):
    acq, rec = _two_sensors_with(tmp_path, lambda fake: fake.set_counter(40_000))
    gap, configured = [g for g in acq["gaps"] if g["sensor"] == "a"]
    assert configured["samples"] == 0 and "configured again" in configured["cause"]
    assert "counter jumped" in gap["cause"] and "restarted?" in gap["cause"]
    assert gap["samples"] < 50  # not the 39 s the counter claims
    assert rec.t[-1] < 3.2 and np.all(np.diff(rec.t) > 0)
    assert np.isfinite(rec.samples[:, 0]).mean() > 0.95


def test_a_daq_that_power_cycles_is_configured_again(tmp_path):
    acq, rec = _two_sensors_with(tmp_path, lambda fake: fake.power_cycle())
    causes = [g["cause"] for g in acq["gaps"] if g["sensor"] == "a"]
    assert any("counter jumped" in c for c in causes), causes
    assert any(c.startswith("the restarted DAQ was configured again") for c in causes), causes
    # after the restart the DAQ streams at 1 kHz again, not at its power-up 100 Hz
    later = (rec.t > 1.2) & (rec.t < 2.9)
    assert np.isfinite(rec.samples[later, 0]).mean() > 0.95
    assert np.all(np.diff(rec.samples[later, 0][np.isfinite(rec.samples[later, 0])]) == 1)
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rec")])
    assert info.exit_code == 0, info.output
    assert f"acquisition: {acq['rows']} rows at {acq['rate_hz_achieved']} Hz achieved; " \
        f"{acq['samples_lost']} sample(s) lost" in info.output
    assert "a: 0 sample(s): the restarted DAQ was configured again" in info.output


#: Status bit 9: Fx overloaded (reference section 5).
OVERLOADED_X = 1 << 9


def _acquired_with_status(tmp_path, status):
    """One second from a fake DAQ whose frame ``k`` has status word ``status(k)`` (its Fx
    is ``k``), acquired by the CLI; the recording read back and its acquisition object."""
    with FakeOptoForce(tmp_path / "tty", source=lambda k: (k % 30000, k % 7, k % 11),
                       status=status):
        result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                          "--duration", "1", "--out", str(tmp_path / "rec"),
                                          "--quiet"])
    assert result.exit_code == 0, result.output
    rec = read_recording(tmp_path / "rec", on_error="flag")
    return rec, rec.extra["acquisition"]


def test_info_reads_a_hand_edited_acquisition_object(tmp_path):
    from dataclasses import replace

    from frictionfit.recording import Recording, write_recording

    rec = Recording.from_arrays(np.zeros((5, 1)), 1000.0, ["s1_x"])
    acq = {"rows": 5, "gaps": 3, "sensors": [{"samples_lost": "many", "gaps_unlisted": 2},
                                             {"samples_lost": 4.0}, "x"]}
    write_recording(replace(rec, extra={"acquisition": acq}), tmp_path / "edited")
    info = CliRunner().invoke(app, ["info", str(tmp_path / "edited")])
    assert info.exit_code == 0, info.output
    assert "acquisition: 5 rows at ? Hz achieved; 4 sample(s) lost" in info.output
    assert "... and 2 more counted, not listed" in info.output


def test_overloaded_samples_are_kept_and_named_on_reading(tmp_path):
    rec, acq = _acquired_with_status(
        tmp_path, lambda k: OVERLOADED_X if 200 <= k < 300 else 0)
    (run,) = acq["overloads"]
    assert run["channel"] == "s1_x" and run["samples"] == 100
    assert acq["sensors"][0]["frames_overloaded"] == 100
    k = rec.samples[:, 0]
    assert run["t"] == pytest.approx(rec.t[k == 200][0])  # the run starts at frame 200
    assert np.isfinite(k).all()  # the values are kept
    (problem,) = [p for p in rec.problems if p.kind == "overload"]
    assert problem.channel == "s1_x" and str(problem).startswith(
        "channel 's1_x': 100 sample(s) overloaded by the DAQ's status")
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rec")])
    assert "problem [overload]: channel 's1_x': 100 sample(s)" in info.output
    assert read_recording(tmp_path / "rec").n_samples == rec.n_samples  # informational


def test_overloaded_runs_beyond_the_list_are_counted_and_named(tmp_path, monkeypatch):
    monkeypatch.setattr(stream_module, "MAX_GAPS_LISTED", 10)
    rec, acq = _acquired_with_status(
        tmp_path, lambda k: OVERLOADED_X if 200 <= k < 300 and k % 2 else 0)
    assert len(acq["overloads"]) == 10 and acq["sensors"][0]["overloads_unlisted"] == 40
    unlisted = [str(p) for p in rec.problems if p.kind == "overload" and p.channel is None]
    assert unlisted == ["sensor 's1': 40 more overloaded run(s) than the sidecar lists; "
                        "their samples are not marked and the fits keep them"]


def test_two_ports_share_one_grid(tmp_path):
    with FakeOptoForce(tmp_path / "a", seed=1) as fa, FakeOptoForce(tmp_path / "b", seed=2):
        result = CliRunner().invoke(app, [
            "acquire", "--port", str(tmp_path / "a"), "--port", str(tmp_path / "b"),
            "--name", "thumb", "--name", "index", "--duration", "1", "--out",
            str(tmp_path / "rec"), "--quiet"])
        assert result.exit_code == 0, result.output
    rec = read_recording(tmp_path / "rec", on_error="flag")
    assert rec.channel_names == ("thumb_x", "thumb_y", "thumb_z", "index_x", "index_y", "index_z")
    acq = rec.extra["acquisition"]
    assert acq["sensor_serial"] == ["ISE0A129", "ISE0A129"]
    assert acq["sensors"][0]["frames_valid"] == fa.frames_sent
    # the second sensor starts (and stops) some ms after the first: NaN at the edges only
    full = np.isfinite(rec.samples).all(axis=1)
    assert full.mean() > 0.95 and full[100:-100].all()


def test_sensitivity_gives_newtons(tmp_path):
    sens = tmp_path / "sens.json"
    sens.write_text(json.dumps({"ISE0A129": [400.9]}))
    with FakeOptoForce(tmp_path / "tty", source=lambda k: (401, -802, 16037)):
        result = CliRunner().invoke(app, [
            "acquire", "--port", str(tmp_path / "tty"), "--duration", "0.3", "--out",
            str(tmp_path / "rec"), "--sensitivity", str(sens), "--quiet"])
    assert result.exit_code == 0, result.output
    rec = read_recording(tmp_path / "rec", on_error="flag")
    assert {c.unit for c in rec.channels} == {"N"}
    np.testing.assert_allclose(rec.samples[0], [401 / 400.9, -802 / 400.9, 16037 / 400.9],
                               rtol=1e-6)


def test_acquire_bad_port_exits_in_words(tmp_path):
    result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "none"),
                                      "--duration", "1", "--out", str(tmp_path / "r")])
    assert result.exit_code == 1
    assert "none: cannot open the port" in result.output


@pytest.mark.parametrize(("options", "words"), [
    (["--out", "{tmp}/file/rec"], "--out: {tmp}/file: cannot make the folder"),
    (["--out", "{tmp}/rec", "--duration", "-1"], "--duration: must be >= 0 s"),
    (["--out", "{tmp}/rec", "--name", "thumb", "--port", "{tmp}/b", "--name", "thumb"],
     "--name: channel name 'thumb' appears twice"),
    (["--out", "{tmp}/rec", "--name", "a,b"], "--name: channel name 'a,b' holds a comma"),
])
def test_acquire_refuses_its_options_before_opening_a_port(tmp_path, options, words):
    (tmp_path / "file").write_text("a file where a folder should be")
    result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "none"),
                                      *(o.format(tmp=tmp_path) for o in options)])
    assert result.exit_code == 2
    assert words.format(tmp=tmp_path) in " ".join(result.output.split())
    assert "cannot open the port" not in result.output


def _wait_for_rows(csv, n, timeout=30):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if csv.exists() and csv.read_text().count("\n") > n:
            return
        time.sleep(0.05)
    pytest.fail(f"{csv} never reached {n} rows")


def test_sigkill_loses_at_most_one_second(tmp_path):
    out = tmp_path / "rec"
    with FakeOptoForce(tmp_path / "tty", corrupt_every=200) as fake:
        proc = subprocess.Popen([*CLI, "acquire", "--port", str(tmp_path / "tty"),
                                 "--duration", "60", "--out", str(out), "--quiet"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            _wait_for_rows(out.with_suffix(".csv"), 1500)
            time.sleep(0.2)  # just before the next flush: the worst moment to die
        finally:
            sent, corrupted = fake.frames_sent, fake.frames_corrupted
            proc.send_signal(signal.SIGKILL)
            proc.communicate(timeout=30)
    info = CliRunner().invoke(app, ["info", str(out)])
    assert info.exit_code == 0, info.output
    rec = read_recording(out, on_error="flag")
    assert f"acquisition: interrupted (status 'recording'): {rec.n_samples} rows in the CSV" \
        in info.output
    missing = sent - corrupted - rec.n_samples
    print(f"SIGKILL after {sent} frames sent: {missing} valid frames missing from the file")
    assert 0 <= missing <= 1000
    assert rec.extra["acquisition"]["status"] == "recording"  # never finalised: it crashed


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_ctrl_c_stop_cleanly(tmp_path, sig):
    out = tmp_path / "rec"
    with FakeOptoForce(tmp_path / "tty") as fake:
        proc = subprocess.Popen([*CLI, "acquire", "--port", str(tmp_path / "tty"),
                                 "--out", str(out), "--quiet"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            _wait_for_rows(out.with_suffix(".csv"), 500)
        finally:
            os.kill(proc.pid, sig)
            stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    rec = read_recording(out)
    acq = rec.extra["acquisition"]
    assert acq["status"] == "interrupted" and "interrupted" in stdout
    assert rec.n_samples == fake.frames_sent  # the DAQ was stopped, every frame drained


def test_power_cut_mid_line_still_reads(tmp_path):
    """A row cut short by a power failure is read as NaN and flagged, never a crash."""
    writer = RecordingWriter(tmp_path / "cut", [Channel("s1_x", "N"), Channel("s1_y", "N")],
                             1000.0)
    writer.start()
    writer.append(np.arange(3), np.ones((3, 2)))
    writer.close({"status": "recording"})
    with open(tmp_path / "cut.csv", "a") as fh:
        fh.write("0.003000,1.5")  # the last row, half written
    info = CliRunner().invoke(app, ["info", str(tmp_path / "cut")])
    assert info.exit_code == 0, info.output
    assert "problem [nonfinite]: channel 's1_y'" in info.output


def test_333_hz_uses_the_exact_rate_and_the_counter_step(tmp_path):
    with FakeOptoForce(tmp_path / "tty") as fake:
        result = CliRunner().invoke(app, ["acquire", "--port", str(tmp_path / "tty"),
                                          "--rate", "333", "--duration", "1", "--out",
                                          str(tmp_path / "rec"), "--quiet"])
    assert result.exit_code == 0, result.output
    rec = read_recording(tmp_path / "rec")  # clean: no gap, the rate matches
    assert rec.sample_rate_hz == pytest.approx(1000 / 3)
    assert fake.configs[-2].speed == 3  # the last one is the stop (speed 0)
    assert rec.extra["acquisition"]["samples_lost"] == 0 and rec.n_samples == fake.frames_sent
