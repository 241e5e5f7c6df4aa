"""Bad input through the command line: no recording is ever written over, a bad file costs
no more than itself and is skipped by name, a wrong result never says converged, and every
message names the file and the problem (the README's rules for bad input)."""

from __future__ import annotations

import hashlib
import json
import shutil
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from frictionfit.cli import app
from frictionfit.errors import RecordingError, Status
from frictionfit.recording import read_dataset, read_recording, write_recording

pytestmark = pytest.mark.usefixtures("feature_cache")

runner = CliRunner()
DATA = Path(__file__).resolve().parents[1] / "data"
SAMPLES = ("s1_paper-1_01", "s1_paper-2_01", "s1_cushion-1_01")


def _sums(folder: Path) -> dict[str, str]:
    """Checksum of every file in ``folder`` (recursively), by relative path."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def lab(tmp_path) -> Path:
    """Three sample recordings of data/ copied into a folder of their own."""
    folder = tmp_path / "lab"
    folder.mkdir()
    for name in SAMPLES:
        for suffix in (".csv", ".json"):
            shutil.copy(DATA / f"{name}{suffix}", folder / f"{name}{suffix}")
    return folder


def _edited(folder: Path, name: str, edit_csv=None, edit_side=None) -> Path:
    """A copy of sample ``SAMPLES[0]`` as ``name`` in ``folder``, its table and sidecar
    passed through ``edit_csv`` (a DataFrame, changed in place or returned) and ``edit_side``
    (a dict, changed in place)."""
    frame = pd.read_csv(DATA / f"{SAMPLES[0]}.csv")
    side = json.loads((DATA / f"{SAMPLES[0]}.json").read_text())
    if edit_csv is not None:
        edited = edit_csv(frame)  # in place, or a new frame
        frame = frame if edited is None else edited
    if edit_side is not None:
        edit_side(side)
    frame.to_csv(folder / f"{name}.csv", index=False, float_format="%.12g")
    (folder / f"{name}.json").write_text(json.dumps(side))
    return folder / f"{name}.csv"


def _last_stamp(value: float):
    def edit(frame):
        frame.loc[len(frame) - 1, "t"] = value
    return edit


def _scaled(factor: float):
    def edit(frame):
        frame.iloc[:, 1:] *= factor
    return edit


# --- no command writes over a recording --------------------------------------------------

def _writers(lab: Path, target: str) -> list[list[str]]:
    """Every command that writes a file, asked to write ``target``."""
    rec = str(lab / f"{SAMPLES[0]}.csv")
    ds = f"recordings:{lab}"
    return [
        ["fit", rec, "--out", target],
        ["fit", rec, "--motions", "--out", target],
        ["fit", str(lab), "--rig", "session", "--save-rig", target],
        ["features", "--dataset", ds, "--out", target],
        ["train", "--dataset", ds, "--out", target],
        ["predict", str(lab / "model.skops"), "--dataset", ds, "--out", target],
        ["evaluate", "--dataset", ds, "--out", target],
        ["evaluate", "--dataset", ds, "--predictions", target],
        ["evaluate", "--dataset", ds, "--results", target],
        ["plot", rec, "--out", target],
        ["bench", "fit", "--out", str(Path(target).parent), "--results", target],
    ]


@pytest.mark.parametrize("which", [f"{SAMPLES[0]}.csv", f"{SAMPLES[0]}.json",
                                   f"{SAMPLES[1]}.csv", f"{SAMPLES[1]}.json"])
def test_no_command_writes_over_a_recording_whatever_out_says(lab, which):
    before = _sums(lab)
    for args in _writers(lab, str(lab / which)):
        for extra in ([], ["--overwrite"]):
            result = runner.invoke(app, [*args, *extra])
            assert result.exit_code == 2, (args, result.output)
            assert "is a recording: frictionfit never writes over a recording" in \
                result.output or "write ." in result.output, (args, result.output)
            assert "Traceback" not in result.output
    assert _sums(lab) == before


def test_the_refusals_name_the_recording_and_the_suffix(lab):
    rec = lab / f"{SAMPLES[0]}.csv"
    result = runner.invoke(app, ["fit", str(rec), "--out", str(rec)])
    assert result.exit_code == 2 and f"{rec} is a recording" in result.output
    result = runner.invoke(app, ["train", "--dataset", f"recordings:{lab}", "--out",
                                 str(rec.with_suffix(".json"))])
    assert result.exit_code == 2 and "write .skops" in result.output
    result = runner.invoke(app, ["plot", str(rec), "--out", str(lab / "x.csv")])
    assert result.exit_code == 2 and "x.csv: write .png, .pdf, .svg" in result.output
    assert not (lab / "x.csv").exists()


def test_a_lone_sidecar_and_a_fabricslide_file_are_recordings_too(lab, tmp_path):
    side = tmp_path / "orphan.json"
    shutil.copy(lab / f"{SAMPLES[0]}.json", side)
    slide = tmp_path / "Linen_F120_V20mmps_0.csv"
    slide.write_text("timestamp, proximity1, proximity2, channel1\n0, 1, 2, 3\n")
    before = _sums(tmp_path)
    for target in (side, slide):
        args = (["fit", str(lab / f"{SAMPLES[0]}.csv"), "--rig", "session", "--save-rig"]
                if target.suffix == ".json" else ["features", "--dataset", f"recordings:{lab}",
                                                  "--out"])
        result = runner.invoke(app, [*args, str(target), "--overwrite"])
        assert result.exit_code == 2 and "is a recording" in result.output, result.output
    assert _sums(tmp_path) == before


def test_a_file_the_command_reads_is_never_written(lab):
    notes = lab / "notes.csv"  # not a recording, but in the folder the command reads
    notes.write_text("a,b\n1,2\n")
    before = _sums(lab)
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{lab}", "--out",
                                 str(notes), "--overwrite"])
    assert result.exit_code == 2 and "is a file this command reads" in result.output
    assert _sums(lab) == before


def test_an_existing_output_is_replaced_only_with_overwrite(lab, tmp_path):
    old = {}
    for name in ("fits.csv", "rigs.json", "f.csv", "m.skops", "p.csv", "s.csv", "x.png"):
        old[name] = tmp_path / name
        old[name].write_text("an earlier output\n")
    rec, ds = str(lab / f"{SAMPLES[0]}.csv"), f"recordings:{lab}"
    for args in (["fit", rec, "--out", str(old["fits.csv"])],
                 ["fit", str(lab), "--rig", "session", "--save-rig", str(old["rigs.json"])],
                 ["features", "--dataset", ds, "--out", str(old["f.csv"])],
                 ["train", "--dataset", ds, "--out", str(old["m.skops"])],
                 ["predict", str(old["m.skops"]), "--dataset", ds, "--out", str(old["p.csv"])],
                 ["evaluate", "--dataset", ds, "--out", str(old["s.csv"])],
                 ["evaluate", "--dataset", ds, "--confusion", str(old["x.png"])],
                 ["plot", rec, "--out", str(old["x.png"])]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert "exists: add --overwrite to replace it" in result.output, (args, result.output)
    assert all(p.read_text() == "an earlier output\n" for p in old.values())
    before = _sums(lab)
    result = runner.invoke(app, ["plot", rec, "--out", str(old["x.png"]), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert old["x.png"].read_bytes()[:4] == b"\x89PNG"
    result = runner.invoke(app, ["features", "--dataset", ds, "--features", "physical",
                                 "--out", str(old["f.csv"]), "--overwrite"])
    assert result.exit_code == 0, result.output
    assert len(pd.read_csv(old["f.csv"])) == 3
    assert _sums(lab) == before


def test_fit_plots_are_not_replaced_without_overwrite(lab, tmp_path):
    plots = tmp_path / "plots"
    plots.mkdir()
    png = plots / f"{SAMPLES[0]}__thumb_x.png"
    png.write_text("an earlier plot")
    result = runner.invoke(app, ["fit", str(lab / f"{SAMPLES[0]}.csv"), "--out",
                                 str(tmp_path / "fits.csv"), "--plot", str(plots)])
    assert result.exit_code == 2 and f"{png} exists: add --overwrite" in result.output
    assert png.read_text() == "an earlier plot" and not (tmp_path / "fits.csv").exists()


# --- a bad file costs no more than itself ------------------------------------------------

def test_a_corrupted_time_stamp_disqualifies_the_recording_by_name(tmp_path):
    bad = _edited(tmp_path, "stamp", _last_stamp(1e6))
    rec = read_recording(bad, on_error="flag")
    assert [p.kind for p in rec.disqualified] == ["time_span"]
    assert "gap" not in [p.kind for p in rec.problems]  # not a plain gap
    with pytest.raises(RecordingError, match=r"stamp.csv: its time stamps span 1e\+06 s "
                       r"\(1e\+09 samples at 1000 Hz\) but the file holds 10006 rows"):
        read_recording(bad)
    from frictionfit.segmentation import regrid

    with pytest.raises(RecordingError, match="more missing samples than the recording holds"):
        regrid(rec)  # refuses to allocate 1e9 rows


def test_info_on_a_corrupted_time_stamp_says_unusable_and_fails(tmp_path):
    bad = _edited(tmp_path, "stamp", _last_stamp(1e6))
    result = runner.invoke(app, ["info", str(bad)])
    assert result.exit_code == 1
    assert "problem [time_span]" in result.output and "[gap]" not in result.output
    assert f"error: {bad}: unusable, every command skips it: [time_span]" in result.output


def test_commands_on_the_corrupted_file_alone_fail_in_words(tmp_path):
    bad = _edited(tmp_path, "stamp", _last_stamp(1e6))
    for args in (["fit", str(bad), "--out", str(tmp_path / "f.csv")],
                 ["fit", str(bad), "--motions", "--out", str(tmp_path / "f.csv")],
                 ["plot", str(bad), "--out", str(tmp_path / "p.png")]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert "stamp.csv" in result.output and "time stamps span" in result.output
        assert result.exception is None or isinstance(result.exception, SystemExit)


def test_a_folder_skips_the_corrupted_file_and_writes_the_others(lab, tmp_path):
    _edited(lab, "stamp", _last_stamp(1e6))
    before = _sums(lab)
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{lab}", "--features",
                                 "physical", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "skipped " in result.output and "stamp.csv: its time stamps span" in result.output
    assert "using 3 recordings; 1 skipped" in result.output
    assert sorted(pd.read_csv(out)["recording"]) == sorted(SAMPLES)
    assert _sums(lab) == before


def test_reading_a_corrupted_file_costs_no_more_than_a_good_one(tmp_path):
    good = _edited(tmp_path, "good")
    # 100 s for 10,006 rows at 1 kHz: a grid of ten times the rows, were it built
    bad = _edited(tmp_path, "stamp", _last_stamp(100.0))
    from frictionfit.errors import FrictionfitError
    from frictionfit.segmentation import segment

    peaks = []
    for path in (good, bad):
        tracemalloc.start()
        try:
            segment(read_recording(path, on_error="flag"))
        except FrictionfitError:
            pass
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] <= 2 * peaks[0], peaks


# --- a wrong result never says converged -------------------------------------------------

def test_forces_beyond_a_tactile_sensor_are_disqualifying(lab, tmp_path):
    giga = _edited(lab, "giga", _scaled(1e9))
    rec = read_recording(giga, on_error="flag")
    assert {p.kind for p in rec.disqualified} == {"force_range"}
    assert "beyond what a tactile sensor measures" in str(rec.disqualified[0])
    result = runner.invoke(app, ["fit", str(giga), "--out", str(tmp_path / "f.csv")])
    assert result.exit_code == 2 and "converged" not in result.output
    assert "skipped " in result.output and "giga.csv: channel 'thumb_x'" in result.output
    with pytest.warns(UserWarning, match=r"skipped .*giga.csv: .*N at t="):
        assert len(read_dataset(lab)) == 3


def test_a_scale_parameter_at_its_bound_is_not_converged():
    from frictionfit.fit._stats import status_of

    mask = np.ones(100, dtype=bool)
    args = (3, True, np.zeros(3), 1.0, 10.0, mask)
    assert status_of(*args) == Status.CONVERGED
    assert status_of(*args, flags={"relax_frac": "at bound"}) == Status.CONVERGED
    for name in ("k", "f_kin"):
        assert status_of(*args, flags={name: "at bound"}) == Status.AT_BOUND
    assert "not measurements" in Status.AT_BOUND.message


@pytest.mark.slow
def test_a_fit_of_forces_a_million_times_too_small_says_at_bound(tmp_path):
    micro = _edited(tmp_path, "micro", _scaled(1e-6))
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["fit", str(micro), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "'converged'" not in result.output and "at_bound" in result.output
    assert set(pd.read_csv(out)["status"]) == {"at_bound"}


def test_a_declared_rate_a_little_off_is_named_and_a_larger_one_disqualifies(tmp_path):
    def rate(hz):
        return lambda side: side.update(sample_rate_hz=hz)

    rec = read_recording(_edited(tmp_path, "r1015", edit_side=rate(1015.0)), on_error="flag")
    off = [p for p in rec.problems if p.kind == "rate_off"]
    assert off and not rec.disqualified
    assert "the time stamps are 1000 Hz, 1.5 % under the sidecar's sample_rate_hz=1015" in \
        str(off[0])
    rec = read_recording(_edited(tmp_path, "r1030", edit_side=rate(1030.0)), on_error="flag")
    assert [p.kind for p in rec.disqualified] == ["sample_rate"]
    rec = read_recording(_edited(tmp_path, "r1001", edit_side=rate(1001.0)), on_error="flag")
    assert not [p for p in rec.problems if p.kind in ("rate_off", "sample_rate")]


def test_predict_names_recordings_at_another_rate_than_training(lab, tmp_path):
    model = tmp_path / "m.skops"
    result = runner.invoke(app, ["train", "--dataset", f"recordings:{lab}", "--features",
                                 "physical", "--no-calibrate", "--out", str(model)])
    assert result.exit_code == 0, result.output
    half = tmp_path / "half"
    for path in sorted(lab.glob("*.csv")):
        rec = read_recording(path, on_error="flag")
        write_recording(type(rec)(rec.t[::2], rec.samples[::2], 500.0, rec.channels,
                                  rec.events, rec.metadata, name=rec.name), half / rec.name)
    out = tmp_path / "p.csv"
    result = runner.invoke(app, ["predict", str(model), "--dataset", f"recordings:{half}",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    # said once, in the rig's line; each recording named in the problems column
    assert sum("500" in line for line in result.output.splitlines()) == 1
    assert "sample rate 500 Hz (trained: 1000 Hz)" in result.output
    problems = pd.read_csv(out)["problems"]
    assert problems.str.contains("recorded at 500 Hz; m.skops was trained at 1000 Hz").all()
    result = runner.invoke(app, ["predict", str(model), "--dataset", f"recordings:{lab}",
                                 "--out", str(tmp_path / "q.csv")])
    assert result.exit_code == 0 and "other_rate" not in result.output


# --- messages that name the file and the problem -----------------------------------------

SLIDE_HEADER = "timestamp, proximity1, proximity2, " + ", ".join(
    f"channel{i}" for i in range(1, 17))


def _slide(path: Path) -> Path:
    rows = [", ".join(map(str, [1000 + 50 * i, 1, 2, *range(16)])) for i in range(600)]
    path.write_text(SLIDE_HEADER + "\n" + "\n".join(rows) + "\n")
    return path


def test_a_fabricslide_file_or_folder_read_as_recordings_says_fabricslide(tmp_path):
    slide = _slide(tmp_path / "Linen_F120_V20mmps_0.csv")
    _slide(tmp_path / "Canvas_F120_V20mmps_0.csv")
    result = runner.invoke(app, ["info", str(slide)])
    assert result.exit_code == 2
    assert f"a FabricSlide slide, not a recording with a sidecar: read it as fabricslide:{slide}" \
        in result.output
    result = runner.invoke(app, ["info", str(tmp_path)])
    assert result.exit_code == 1
    assert (f"its 2 .csv files are FabricSlide slides, not recordings with sidecars: read the "
            f"folder as fabricslide:{tmp_path}") in result.output
    result = runner.invoke(app, ["info", f"fabricslide:{tmp_path}"])
    assert result.exit_code == 0, result.output
    assert "no session(s)" in result.output and "sNone" not in result.output


def test_info_on_the_shared_fabricslide_folder_says_what_it_is(shared):
    folder = shared / "datasets" / "fabricslide"
    n = len(list(folder.glob("*.csv")))
    result = runner.invoke(app, ["info", str(folder)])
    assert result.exit_code == 1
    assert (f"its {n} .csv files are FabricSlide slides, not recordings with sidecars: read the "
            f"folder as fabricslide:{folder}") in result.output
    assert f"... and {n - 10} more skipped" in result.output  # not n lines


def test_a_folder_none_of_whose_recordings_can_be_used_says_why(tmp_path):
    _edited(tmp_path, "giga1", _scaled(1e9))
    _edited(tmp_path, "stamp", _last_stamp(1e6))
    result = runner.invoke(app, ["info", str(tmp_path)])
    assert result.exit_code == 1
    assert "none of its 2 recordings could be used: 1 x " in result.output
    assert "time stamps span" in result.output and "tactile sensor" in result.output


def test_a_malformed_event_is_named(tmp_path):
    def drop_t(side):
        del side["events"][2]["t"]

    bad = _edited(tmp_path, "ev", edit_side=drop_t)
    with pytest.raises(RecordingError, match=r"ev.json: malformed event 2 in sidecar "
                       r"\{\"kind\": \"move\", \"target\": \"p2\".*: no 't'"):
        read_recording(bad)


def test_an_empty_folder_is_said_to_be_empty(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    result = runner.invoke(app, ["fit", str(empty), "--out", str(tmp_path / "f.csv")])
    assert result.exit_code == 2 and "empty: the folder is empty of recordings" in result.output
    result = runner.invoke(app, ["info", str(empty)])
    assert result.exit_code == 1 and "no <name>.csv + <name>.json recordings found" in \
        result.output


def test_a_truncated_model_file_is_damaged(lab, tmp_path):
    import zipfile

    model = tmp_path / "m.skops"
    with zipfile.ZipFile(model, "w") as z:
        z.writestr("schema.json", "{}" * 4000)
    cut = tmp_path / "cut.skops"
    cut.write_bytes(model.read_bytes()[:1000])
    result = runner.invoke(app, ["predict", str(cut), "--dataset", f"recordings:{lab}", "--out",
                                 str(tmp_path / "p.csv")])
    assert result.exit_code == 1 and "cut.skops: damaged: the model file is cut short" in \
        result.output


def test_no_move_events_is_said_once_and_suggests_motions(lab, tmp_path):
    bare = _edited(lab, "bare", edit_side=lambda side: side.update(events=[]))
    result = runner.invoke(app, ["fit", str(bare), "--out", str(tmp_path / "f.csv")])
    assert result.exit_code == 2 and result.output.count("no 'move' events") == 1, result.output
    assert "bare: no 'move' events: a whole fit needs the motor's commands; fit the motions " \
        "found in the force with --motions" in result.output


def test_warnings_reach_the_user_as_one_plain_line(monkeypatch, tmp_path):
    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)  # restored after
    result = runner.invoke(app, ["info", str(tmp_path / "x.csv")])
    assert result.exit_code == 2
    shown = [warnings.formatwarning("Mean of empty slice", RuntimeWarning, "/x/numpy.py", 3)
             for _ in range(2)]
    assert shown == ["warning: Mean of empty slice\n", ""]  # no file, line or category; once
    with pytest.warns(RuntimeWarning, match="still recorded"):  # callers still receive them
        warnings.warn("still recorded", RuntimeWarning, stacklevel=1)


def test_long_commands_say_each_stage_off_a_terminal(lab, tmp_path):
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{lab}", "--features",
                                 "physical", "--out", str(tmp_path / "f.csv")])
    assert result.exit_code == 0, result.output
    assert "features (physical) of 3 recordings ..." in result.output
    assert "features (physical) of 3 recordings: done in " in result.output


def test_the_guide_states_the_rules_the_code_applies():
    from frictionfit import recording

    root = Path(__file__).resolve().parents[1]
    text = " ".join((root / "docs" / "guide.md").read_text().split())
    assert "docs/guide.md" in (root / "README.md").read_text()
    assert "rate 0.5-2 % off the time stamps' (`rate_off`" in text
    assert (recording.RATE_NOTE, recording.RATE_TOLERANCE) == (0.005, 0.02)
    assert "rate_off" in recording.INFORMATIONAL
    assert "a sidecar rate more than 2 % off the data's" in text
    assert "more missing samples than the file has rows (`time_span`" in text
    assert recording.GRID_LIMIT == 2 and "time_span" in recording.DISQUALIFYING
    assert "forces beyond 10 kN (`force_range`" in text and recording.FORCE_LIMIT_N == 1e4
    assert "force_range" in recording.DISQUALIFYING
    assert "status `at_bound`, never `converged`" in text
    assert "replaced only with `--overwrite`" in text


@pytest.mark.parametrize("edit, words", [
    (lambda frame: frame.iloc[:0], "only 0 sample"),
    (_last_stamp(np.nan), "column 't' has NaN/inf"),
    (lambda frame: frame.loc.__setitem__((500, "t"), 0.1), "time is not strictly increasing"),
])
def test_plot_of_time_stamps_no_grid_can_hold_fails_in_words(tmp_path, edit, words):
    bad = _edited(tmp_path, "bad", edit)
    result = runner.invoke(app, ["plot", str(bad), "--out", str(tmp_path / "p.png")])
    assert result.exit_code == 2 and f"{bad}: " in result.output and words in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    from frictionfit.segmentation import regrid

    with pytest.raises(RecordingError, match="no uniform grid"):
        regrid(read_recording(bad, on_error="flag"))


def test_the_demo_never_writes_its_table_into_the_recordings_it_reads(lab):
    (lab / "fits.csv").write_text("a,b\n")
    before = _sums(lab)
    result = runner.invoke(app, ["demo", "--data", str(lab), "--out", str(lab)])
    assert result.exit_code == 2 and "fits.csv is a file this command reads" in result.output
    assert _sums(lab) == before


def test_a_link_to_a_recording_is_a_recording(lab, tmp_path):
    link = tmp_path / "fits.csv"
    link.symlink_to(lab / f"{SAMPLES[0]}.csv")
    before = _sums(lab)
    result = runner.invoke(app, ["fit", str(lab / f"{SAMPLES[1]}.csv"), "--out", str(link),
                                 "--overwrite"])
    assert result.exit_code == 2 and "is a recording" in result.output
    assert _sums(lab) == before


def test_fit_says_each_stage_off_a_terminal(tmp_path):
    from frictionfit.recording import Event, Recording
    from frictionfit.simulation.trials import simulate_trials

    ts = simulate_trials("elastic_plastic", 2, seed=4, snr_db=30)
    events = [Event(ts.t_out + 2 * k + dt, "move", tgt)
              for k in range(2) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    write_recording(Recording.from_arrays(ts.y.reshape(-1, 1), 1000.0, ["index_x"],
                                          events=events), tmp_path / "m1")
    result = runner.invoke(app, ["fit", str(tmp_path / "m1.csv"), "--motions", "--model",
                                 "elastic_plastic", "--uncertainty", "laplace", "--out",
                                 str(tmp_path.parent / f"{tmp_path.name}.csv")])
    assert result.exit_code == 0, result.output
    for words in ("fitting 1 trial", "posteriors (laplace) of 1 trial"):
        assert f"{words} ...\n" in result.output and f"{words}: done in " in result.output
