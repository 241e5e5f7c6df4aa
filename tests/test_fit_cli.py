"""``frictionfit fit`` end to end: a row per motion x channel, bad files named, options."""

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from frictionfit.cli import app
from frictionfit.recording import Event, Recording, write_recording
from frictionfit.simulation.trials import simulate_trials


def _measurement(tmp_path):
    ts = simulate_trials("elastic_plastic", 2, seed=4, snr_db=30)
    samples = np.concatenate([ts.y.T, ts.y.T])  # two 2-s motions, two channels
    events = [Event(ts.t_out + 2 * k + dt, "move", tgt)
              for k in range(2) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    rec = Recording.from_arrays(samples, 1000.0, ["index_x", "thumb_x"], events=events)
    write_recording(rec, tmp_path / "m1")


def test_fit_plots_fixes_and_ties(tmp_path):
    _measurement(tmp_path)
    out, plots = tmp_path / "fits.parquet", tmp_path / "png"
    result = CliRunner().invoke(app, [
        "fit", str(tmp_path / "m1.csv"), "--model", "elastic_plastic", "--out", str(out),
        "--plot", str(plots), "--fix", "delay=0.02", "--tie", "ramp"])
    assert result.exit_code == 0, result.output
    frame = pd.read_parquet(out)
    assert np.allclose(frame["delay [s]"], 0.02) and set(frame["delay_flag"]) == {"fixed"}
    assert frame["ramp [s]"].nunique() == 1 and set(frame["ramp_flag"]) == {"tied"}
    assert sorted(p.name for p in plots.iterdir()) == [
        "m1__motion1__index_x.png", "m1__motion1__thumb_x.png"]


def test_bad_fix_is_named(tmp_path):
    _measurement(tmp_path)
    result = CliRunner().invoke(app, ["fit", str(tmp_path / "m1.csv"), "--fix", "tau"])
    assert result.exit_code == 2 and "write NAME=VALUE" in result.output


def test_fit_writes_one_row_per_motion_and_channel(tmp_path):
    _measurement(tmp_path)
    (tmp_path / "broken.csv").write_text("t,x\n0,1\n")  # no sidecar: skipped, named
    out = tmp_path / "fits.csv"
    result = CliRunner().invoke(app, ["fit", str(tmp_path), "--model", "elastic_plastic",
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "broken.json: sidecar file is missing" in result.output
    frame = pd.read_csv(out)
    assert list(frame["trial"]) == ["m1/motion1/index_x", "m1/motion1/thumb_x"]
    assert {"k [N/mm]", "status"} <= set(frame.columns)


def test_fit_with_nothing_to_fit_exits_2(tmp_path):
    result = CliRunner().invoke(app, ["fit", str(tmp_path)])
    assert result.exit_code == 2 and "no motion could be segmented" in result.output


def test_fit_on_a_dask_scheduler_equals_the_local_fit(tmp_path):
    distributed = __import__("pytest").importorskip("distributed")
    _measurement(tmp_path)
    args = ["fit", str(tmp_path / "m1.csv"), "--model", "elastic_plastic",
            "--uncertainty", "laplace"]
    local, remote = tmp_path / "local.csv", tmp_path / "remote.csv"
    assert CliRunner().invoke(app, [*args, "--out", str(local)]).exit_code == 0
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        result = CliRunner().invoke(app, [*args, "--out", str(remote),
                                          "--scheduler", cluster.scheduler_address])
    assert result.exit_code == 0, result.output
    a, b = pd.read_csv(local), pd.read_csv(remote)
    assert list(a["trial"]) == list(b["trial"])
    for column in ("k [N/mm]", "f_kin [N]", "f_kin_sd [N]"):
        np.testing.assert_allclose(b[column], a[column], rtol=1e-6)
