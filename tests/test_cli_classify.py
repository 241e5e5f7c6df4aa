"""``frictionfit features|train|predict|evaluate`` through typer's CliRunner on simulated data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from frictionfit.calibration import CalibrationWarning
from frictionfit.cli import app
from frictionfit.model_file import load_model
from frictionfit.recording import write_recording
from frictionfit.simulation.measurements import simulate_measurements

pytestmark = pytest.mark.usefixtures("feature_cache")

runner = CliRunner()
LABELS = ("paper-1", "carpet-2", "belt-1")


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """Sessions 1-2 (3 classes x 4 trials) for training, session 3 (1 trial each) held back."""
    specs = [(s, lab, k) for s in (1, 2) for lab in LABELS for k in (1, 2, 3, 4)]
    held = [(3, lab, 1) for lab in LABELS]
    recs = simulate_measurements(specs + held, seed=5, pad_to=len(specs + held))
    train, test = tmp_path_factory.mktemp("train"), tmp_path_factory.mktemp("test")
    for rec in recs:
        write_recording(rec, (test if rec.metadata["session"] == 3 else train) / rec.name)
    return train, test


def test_train_then_predict_round_trip(folders, tmp_path):
    train, test = folders
    model = tmp_path / "m.skops"
    # one session of 12 recordings: too few for 10 neighbours when a session is held out
    with pytest.warns(UserWarning, match="another rig are not tempered: without one session"):
        result = runner.invoke(app, ["train", "--dataset", f"recordings:{train}", "--features",
                                     "handcrafted", "--classifier", "knn", "--out", str(model)])
    assert result.exit_code == 0, result.output
    saved = load_model(model)
    assert saved["rigs"] == [{"name": "frictionfit-simulator", "stroke_mm": None,
                              "sample_rate_hz": 1000.0, "n_recordings": 24,
                              "sessions": ["1", "2"]}]
    assert saved["labels"] == sorted(LABELS)
    assert saved["feature_names"][0] == "thumb_x:out_peak [N]"
    assert saved["n_train"] == 24 and saved["frictionfit_version"]
    out = tmp_path / "p.csv"
    # three recordings of a new session are too few to standardise it by itself: said
    with pytest.warns(UserWarning,
                      match=r"session \['frictionfit-simulator/3'\].*fewer than 10 recordings"):
        result = runner.invoke(app, ["predict", str(model), "--dataset",
                                     f"recordings:{test}", "--out", str(out)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out)
    assert list(table.columns) == ["recording", "predicted", "probability", "true",
                                   "top1", "p1", "top2", "p2", "top3", "p3", "rig_seen",
                                   "problems"]
    assert table["rig_seen"].all()  # session 3 of the training rig: probabilities as they are
    assert "not one the model was trained on" not in result.output
    assert sorted(table["recording"]) == sorted(f"s3_{lab}_01" for lab in LABELS)
    assert set(table["predicted"]) <= set(LABELS)
    assert table["probability"].between(0, 1).all()
    assert (table["probability"] <= table["p1"] + 1e-12).all()
    assert (table["p1"] >= table["p2"]).all()
    *_, ece_line, last = result.output.strip().splitlines()
    assert last.startswith("accuracy: ")
    assert ece_line.startswith("expected calibration error (15 bins): ")
    assert f"on {len(table)} recordings: " in ece_line
    # --abstain: exactly the recordings whose top probability is below it abstain, said
    cut = float(table["probability"].max()) + 1e-9 if table["probability"].max() < 1 else 1.0
    below = int((table["probability"] < cut).sum())
    with pytest.warns(UserWarning, match="fewer than 10 recordings"):
        result = runner.invoke(app, ["predict", str(model), "--dataset", f"recordings:{test}",
                                     "--out", str(out), "--abstain", str(cut), "--overwrite"])
    assert result.exit_code == 0, result.output
    abstained = pd.read_csv(out)
    assert ((abstained["predicted"] == "abstain") == (table["probability"] < cut)).all()
    assert below >= 1
    assert f"abstained on {below} of 3 recordings" in result.output


def test_features_table_has_recording_label_groups_then_features(folders, tmp_path):
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{folders[1]}",
                                 "--features", "fftbins", "--out", str(out)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out)
    assert list(table.columns[:3]) == ["recording", "label", "session"]
    assert table.shape == (3, 3 + 3 + 80)  # + layers, material, problems; 80 FFT bins
    parquet = out.with_suffix(".parquet")
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{folders[1]}",
                                 "--features", "fftbins", "--out", str(parquet)])
    assert result.exit_code == 0, result.output
    pd.testing.assert_frame_equal(pd.read_parquet(parquet), table.fillna({"problems": ""}),
                                  check_dtype=False)


def test_default_features_follow_the_dataset_kind(folders, tmp_path):
    """Rubbing recordings without --features: the measured quantities and the fitted law."""
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{folders[1]}",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    columns = list(pd.read_csv(out).columns)
    assert "physical__index_x:out_static [N]" in columns
    assert "fitted__index_x:fit_k [log10 N/stroke]" in columns  # the simulator declares none


def test_relaxation_flag_keeps_the_relaxation_quantities(folders, tmp_path):
    """--relaxation adds the fitted and measured relaxation quantities; without it, none."""
    columns = {}
    for flag in ("--no-relaxation", "--relaxation"):
        out = tmp_path / f"{flag}.csv"
        result = runner.invoke(app, ["features", "--dataset", f"recordings:{folders[1]}",
                                     "--out", str(out), flag])
        assert result.exit_code == 0, result.output
        columns[flag] = list(pd.read_csv(out).columns)
    relax = [c for c in columns["--relaxation"] if "relax" in c]
    assert any(c.startswith("fitted__") and "relax_frac" in c for c in relax), relax
    assert any(c.startswith("physical__") for c in relax), relax
    assert not [c for c in columns["--no-relaxation"] if "relax" in c]
    assert set(columns["--no-relaxation"]) < set(columns["--relaxation"])


def test_a_model_trained_with_relaxation_keeps_and_records_it(folders, tmp_path):
    model = tmp_path / "m.skops"
    result = runner.invoke(app, ["train", "--dataset", f"recordings:{folders[0]}",
                                 "--features", "fitted", "--relaxation", "--classifier",
                                 "knn", "--no-calibrate", "--out", str(model)])
    assert result.exit_code == 0, result.output
    saved = load_model(model)
    assert saved["relaxation"] is True
    assert any("relax_frac" in n for n in saved["feature_names"]), saved["feature_names"]


def test_gestures_default_to_their_wavelet_features(tmp_path):
    from frictionfit.simulation.gestures import simulate_gestures

    simulate_gestures(tmp_path / "g", people=1, repetitions=1, progress=False)
    out = tmp_path / "f.csv"
    result = runner.invoke(app, ["features", "--dataset", f"gesture:{tmp_path / 'g'}",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "7 recordings x 270 features" in result.output


def test_evaluate_prints_accuracy_last_and_saves(folders, tmp_path):
    out, png, rel, pred = (tmp_path / n for n in ("r.csv", "c.png", "rel.png", "p.csv"))
    # one training session of 12 recordings per fold: too few to hold 10 neighbours out
    with pytest.warns(CalibrationWarning, match="not calibrated: Expected n_neighbors"):
        result = runner.invoke(app, [
            "evaluate", "--dataset", f"recordings:{folders[0]}", "--features", "handcrafted",
            "--classifier", "knn", "--protocol", "leave-one-session-out", "--out", str(out),
            "--confusion", str(png), "--reliability", str(rel), "--predictions", str(pred)])
    assert result.exit_code == 0, result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("accuracy: ") and 0.0 <= float(last.split()[-1]) <= 1.0
    assert list(pd.read_csv(out).columns) == ["features", "classifier", "protocol", "accuracy",
                                              "macro_f1", "ece", "ece_if_calibrated",
                                              "accuracy_at_0.9"]
    assert png.stat().st_size > 0 and rel.stat().st_size > 0
    assert {"recording", "true", "predicted", "probability", "top3"} <= set(pd.read_csv(pred))


def test_evaluate_all_writes_one_row_per_combination(folders, tmp_path):
    out = tmp_path / "all.csv"
    with pytest.warns(CalibrationWarning, match="not calibrated"):  # knn: see above
        result = runner.invoke(app, [
            "evaluate", "--all", "--dataset", f"recordings:{folders[0]}", "--feature-sets",
            "handcrafted;fftbins", "--classifiers", "knn,svm-ovo", "--protocols",
            "leave-one-session-out", "--out", str(out)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out)
    assert len(table) == 4 and set(table["features"]) == {"handcrafted", "fftbins"}


def test_errors_name_the_problem(folders, tmp_path):
    result = runner.invoke(app, ["predict", str(tmp_path / "none.skops"), "--dataset",
                                 f"recordings:{folders[1]}"])
    assert result.exit_code == 1 and "none.skops: model file not found" in result.output
    result = runner.invoke(app, ["evaluate", "--dataset", f"recordings:{folders[0]}",
                                 "--protocol", "leave-one-person-out"])
    assert result.exit_code == 1 and "no metadata 'person'" in result.output
    result = runner.invoke(app, ["train", "--dataset", "nowhere:x"])
    assert result.exit_code == 1 and "unknown dataset kind 'nowhere'" in result.output
    one = tmp_path / "one"
    one.mkdir()
    for src in sorted(folders[0].glob("*.csv"))[:4]:  # the first class only
        for path in (src, src.with_suffix(".json")):
            (one / path.name).write_bytes(path.read_bytes())
    for command, suffix in (("train", ".skops"), ("evaluate", ".csv")):
        result = runner.invoke(app, [command, "--dataset", f"recordings:{one}", "--features",
                                     "handcrafted", "--out", str(tmp_path / f"{command}{suffix}")])
        assert result.exit_code == 1, result.output
        assert "a classifier needs at least two classes of 'label'; all 4 recordings are" \
            in result.output


class _Boom:
    """Unpickling this writes a marker file: the code a crafted model file would run."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


class _Inert:
    """A type no model file of frictionfit holds."""

    value = 1


@pytest.fixture(scope="module")
def model_file(folders, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.skops"
    result = runner.invoke(app, ["train", "--dataset", f"recordings:{folders[0]}", "--features",
                                 "handcrafted", "--classifier", "svm-ovo", "--out", str(path)])
    assert result.exit_code == 0, result.output
    return path


def test_a_crafted_or_damaged_model_file_is_refused_and_runs_no_code(folders, tmp_path,
                                                                     model_file):
    import pickle

    import skops.io

    marker = tmp_path / "ran"
    pickled = tmp_path / "evil.joblib"
    pickled.write_bytes(pickle.dumps({"pipeline": _Boom(str(marker))}))
    crafted = tmp_path / "evil.skops"
    skops.io.dump({"pipeline": _Inert()}, crafted)
    half = tmp_path / "half.skops"
    half.write_bytes(model_file.read_bytes()[: model_file.stat().st_size // 2])
    (tmp_path / "empty.skops").write_bytes(b"")
    (tmp_path / "garbage.skops").write_bytes(b"\x00garbage" * 50)
    cases = {
        pickled: "evil.joblib: not a model written by `frictionfit train` (a pickle/joblib file",
        crafted: "evil.skops: refused: the file holds types frictionfit does not trust "
                 "['test_cli_classify._Inert']",
        half: "half.skops: damaged: the model file is cut short",
        tmp_path / "empty.skops": "empty.skops: the model file is empty",
        tmp_path / "garbage.skops": "garbage.skops: not a model written by `frictionfit train`",
    }
    for path, words in cases.items():
        result = runner.invoke(app, ["predict", str(path), "--dataset",
                                     f"recordings:{folders[1]}"])
        assert result.exit_code == 1 and words in result.output, (path.name, result.output)
    assert not marker.exists()


def test_predict_refuses_recordings_unlike_the_training_ones(folders, tmp_path, model_file):
    from frictionfit.recording import Recording

    rec = next(iter(sorted(folders[1].glob("*.csv"))))
    other = tmp_path / "fs"
    other.mkdir()
    from frictionfit.recording import read_recording

    r = read_recording(rec, on_error="flag")
    renamed = Recording(r.t, r.samples, r.sample_rate_hz,
                        tuple(type(c)(c.name.replace("index", "middle"), c.unit)
                              for c in r.channels), events=r.events, metadata=r.metadata,
                        name=r.name)
    write_recording(renamed, other / r.name)
    result = runner.invoke(app, ["predict", str(model_file), "--dataset", f"recordings:{other}"])
    assert result.exit_code == 1
    assert f"{r.name}: channels ['index_x [N]', 'index_y [N]'] that" in result.output
    assert "m.skops was trained on" in result.output or "are missing" in result.output
    result = runner.invoke(app, ["predict", str(model_file), "--dataset", f"gesture:{other}"])
    assert result.exit_code == 1
    assert "was trained on 'recordings' recordings (handcrafted features), not 'gesture'" \
        in result.output


def test_outputs_that_cannot_be_written_are_refused_before_any_work(folders, tmp_path):
    nowhere = str(tmp_path / "nodir" / "x")
    for args in (["features", "--dataset", f"recordings:{folders[1]}", "--out", nowhere + ".csv"],
                 ["train", "--dataset", f"recordings:{folders[0]}", "--out", nowhere + ".skops"],
                 ["evaluate", "--dataset", f"recordings:{folders[0]}", "--reliability",
                  nowhere + ".png"],
                 ["evaluate", "--dataset", f"recordings:{folders[0]}", "--results",
                  nowhere + ".md"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2 and "does not exist" in result.output, result.output
    file = tmp_path / "file"  # a file where a folder must go
    file.write_text("")
    recording = str(sorted(folders[1].glob("*.csv"))[0])
    for args in (["bench", "fit", "--out", str(file / "bench")],
                 ["plot", recording, "--out", str(file / "p.png")]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2 and "cannot make the folder" in result.output, result.output


def test_problems_found_on_reading_reach_the_feature_table(folders, tmp_path):
    from frictionfit.recording import read_recording

    src = sorted(folders[1].glob("*.csv"))
    for path in src:
        rec = read_recording(path, on_error="flag")
        samples = rec.samples.copy()
        if path == src[0]:
            samples[3000:3040, 2] = np.nan  # a NaN burst in index_x
        write_recording(type(rec)(rec.t, samples, rec.sample_rate_hz, rec.channels,
                                  events=rec.events, metadata=rec.metadata, name=rec.name),
                        tmp_path / rec.name)
    out = tmp_path.parent / f"{tmp_path.name}-f.csv"
    result = runner.invoke(app, ["features", "--dataset", f"recordings:{tmp_path}",
                                 "--features", "fftbins", "--out", str(out)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out).set_index("recording")
    flagged = int(table["problems"].fillna("").str.contains(r"\[nonfinite\]").sum())
    assert f"problems found on reading (kept, masked where they are): nonfinite in {flagged} " \
           "recording(s)" in result.output
    assert "channel 'index_x': 40 NaN/inf sample(s)" in table.loc[src[0].stem, "problems"]


@pytest.fixture(scope="module")
def two_rigs(tmp_path_factory):
    """Simulated rig sim-a (sessions 1-2, 3 classes x 4 trials) and rig sim-b (session 3)."""
    from frictionfit.simulation.rigs import RIGS

    folder = tmp_path_factory.mktemp("rigs")
    specs = [(s, lab, k) for s in (1, 2) for lab in LABELS for k in (1, 2, 3, 4)]
    for rec in simulate_measurements(specs, seed=5, rig=RIGS["sim-a"]):
        write_recording(rec, folder / "a" / rec.name)
    for rec in simulate_measurements([(3, lab, k) for lab in LABELS for k in (1, 2, 3, 4)],
                                     seed=5, rig=RIGS["sim-b"]):
        write_recording(rec, folder / "b" / rec.name)
        write_recording(rec, folder / "a" / f"b_{rec.name}")
    return folder


def test_predict_on_another_rig_says_so_and_tempers(two_rigs, tmp_path):
    model, out = tmp_path / "m.skops", tmp_path / "p.csv"
    train = tmp_path / "train"
    for path in (two_rigs / "a").glob("s*"):
        (train / path.name).parent.mkdir(exist_ok=True)
        (train / path.name).write_bytes(path.read_bytes())
    result = runner.invoke(app, ["train", "--dataset", f"recordings:{train}", "--features",
                                 "handcrafted", "--out", str(model)])
    assert result.exit_code == 0, result.output
    saved = load_model(model)
    assert [(r["name"], r["stroke_mm"], r["sample_rate_hz"]) for r in saved["rigs"]] == [
        ("sim-a", 1.3, 1000.0)]
    result = runner.invoke(app, ["predict", str(model), "--dataset",
                                 f"recordings:{two_rigs / 'b'}", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert ("12 recording(s) of rig 'sim-b' (stroke 0.9 mm, 500 Hz), not one the model was "
            "trained on: another rig; stroke 0.9 mm (trained: 1.3 mm); sample rate 500 Hz "
            "(trained: 1000 Hz)") in result.output
    assert "trained on 'sim-a' (stroke 1.3 mm, 1000 Hz); their probabilities are tempered " \
           "(log-probabilities x" in result.output
    assert "from held-out sessions of the training data)" in result.output
    assert not pd.read_csv(out)["rig_seen"].any()


def test_leave_one_rig_out_needs_two_rigs_and_says_so(folders):
    result = runner.invoke(app, ["evaluate", "--dataset", f"recordings:{folders[0]}",
                                 "--features", "handcrafted", "--protocol", "leave-one-rig-out"])
    assert result.exit_code == 1
    assert ("protocol 'leave-one-rig-out' needs recordings of at least two rigs "
            "(metadata.rig); all are of ['frictionfit-simulator']") in result.output


def test_leave_one_rig_out_tests_each_rig_on_a_model_of_the_others(two_rigs, tmp_path):
    pred = tmp_path / "p.csv"
    with pytest.warns(UserWarning):  # one session held out of 12 recordings is standardised
        result = runner.invoke(app, [  # with the training statistics; calibration too small
            "evaluate", "--dataset", f"recordings:{two_rigs / 'a'}", "--features",
            "handcrafted", "--protocol", "leave-one-rig-out", "--predictions", str(pred)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(pred)
    assert sorted(set(zip(table["fold"], table["rig"], strict=True))) == [(0, "sim-a"),
                                                                          (1, "sim-b")]
    assert result.output.strip().splitlines()[-1].startswith("accuracy: ")
