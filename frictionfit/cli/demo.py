"""``frictionfit demo``: read the sample data in ``data/``, segment, fit, compare, classify."""

from __future__ import annotations

from pathlib import Path

import typer

from frictionfit.cli._load import WHOLE_LAWS_HELP, check_output, reads_of

#: The sample set shipped in ``data/``; ``frictionfit simulate`` remakes it with these.
#: With the motor's position reads at 50 Hz, as ``frictionfit rub`` writes them.
SAMPLE = {"seed": 2026, "sessions": 1, "measurements_per_class": 1,
          "classes": ("paper-1", "paper-2", "cushion-1", "aluminium-foil-1"),
          "position_rate_hz": 50.0}
SAMPLE_COMMAND = ("frictionfit simulate --out data --seed 2026 --sessions 1 "
                  "--measurements-per-class 1 --motor-positions 50 "
                  "--classes paper-1,paper-2,cushion-1,aluminium-foil-1")


def _sample_recordings(data: Path, out: Path) -> list:
    from frictionfit.recording import read_dataset
    from frictionfit.simulation.measurements import simulate_dataset

    if not any(data.glob("*.csv")):
        typer.echo(f"no sample data in {data}; simulating it into {out / 'data'} "
                   f"(same as `{SAMPLE_COMMAND}`)")
        data = out / "data"
        simulate_dataset(data, SAMPLE["seed"], SAMPLE["sessions"],
                         SAMPLE["measurements_per_class"], SAMPLE["classes"],
                         position_rate_hz=SAMPLE["position_rate_hz"])
    return read_dataset(data)


def _classify(recs: list, fitted: bool) -> None:
    """Train on a small simulated set (other sessions) and classify the sample recordings."""
    from frictionfit.classify import labels_of, make_pipeline, projection_for
    from frictionfit.simulation.measurements import simulate_measurements

    classes = sorted({str(r.label) for r in recs})
    specs = [(s, c, t) for s in (2, 3) for c in classes for t in range(1, 5)]
    train = simulate_measurements(specs, SAMPLE["seed"])
    kind = "fitted + measured" if fitted else "measured"
    # one rig (the simulator's) for training and sample data: the relaxation quantities,
    # which another rig's finger would change, describe the material here
    pipe = make_pipeline("physical", "svm-ovo", normalise_by=None, fitted=fitted,
                         relaxation=True, project=projection_for(train))
    predicted = pipe.fit(train, labels_of(train)).predict(recs)
    projected = "project" in pipe.named_steps and pipe.named_steps["project"].lda_ is not None
    typer.echo(f"\nclassification: physical features ({kind}, relaxation included: one rig), "
               f"{'LDA projection + ' if projected else ''}RBF SVM, trained on "
               f"{len(train)} simulated measurements of sessions 2-3")
    for rec, label in zip(recs, predicted, strict=True):
        verdict = "ok" if label == rec.label else "WRONG"
        typer.echo(f"  {rec.name:24s} predicted {label:18s} {verdict}")
    hits = sum(str(p) == str(r.label) for p, r in zip(predicted, recs, strict=True))
    typer.echo(f"accuracy on the sample data: {hits}/{len(recs)}")


def demo(
    data: Path = typer.Option(Path("data"), help="Folder of sample recordings."),
    out: Path = typer.Option(Path("frictionfit-demo"), help="Folder for the demo's outputs."),
    channel: str = typer.Option("index_x", help="Channel to fit."),
    model: str = typer.Option("auto", help="Contact law of the whole-measurement fit: "
                              f"{WHOLE_LAWS_HELP}"),
    classify: bool = typer.Option(True, help="Also train a classifier on simulated sessions "
                                  "and classify the sample data."),
    fitted_features: bool = typer.Option(True, help="Classify with the fitted law's "
                                         "parameters and the measured quantities (the default "
                                         "features of rubbing recordings); --no-fitted-features:"
                                         " the measured quantities alone (about 30 s faster)."),
) -> None:
    """Segment the sample measurements, fit each one whole, compare with the simulator's truth,
    and classify them."""
    import numpy as np

    from frictionfit.segmentation import segment
    from frictionfit.simulation.measurements import measurement_truth
    from frictionfit.whole_fit import fit_recordings

    out.mkdir(parents=True, exist_ok=True)
    # the demo's own fits.csv is written again on every run; never a recording or its data
    check_output(out / "fits.csv", "--out", overwrite=True, reads=reads_of([data]))
    recs = _sample_recordings(data, out)
    typer.echo(f"read {len(recs)} recordings: {', '.join(r.name for r in recs)}")
    n_motions, worst = 0, 0.0
    for rec in recs:
        for m in segment(rec):
            n_motions += 1
            tm = rec.truth["motions"][m.index] if rec.truth else None
            if tm:
                found = [m.t0 + p.start_s for p in m.phases[::2]] + [m.t0 + m.phases[0].stop_s,
                                                                     m.t0 + m.phases[2].stop_s]
                true = [tm["move_out"][0], tm["move_back"][0], tm["move_out"][1],
                        tm["move_back"][1]]
                worst = max(worst, float(np.max(np.abs(np.subtract(found, true)))))
    typer.echo(f"segmented {n_motions} motions (the preparatory one dropped); largest phase "
               f"boundary error against the simulator's motor: {worst * 1e3:.1f} ms")
    result = fit_recordings(recs, channels=[channel], model=model, progress=False)
    result.to_frame(result.ids).to_csv(out / "fits.csv", index=False)
    typer.echo("\n" + result.report(0))
    typer.echo(f"\ntruth/fit ({channel}; each recording fitted whole; truth: median over the "
               "fitted motions, f_kin halfway through the travel; the simulator adds damping "
               "and per-movement timing jitter)")
    names = ("k", "f_kin", "f_static_excess", "relax_frac", "tau")
    typer.echo(f"{'recording':22s} " + " ".join(f"{n:>17s}" for n in names))
    for i, rec in enumerate(recs):
        values = result.params(i)  # its law's own; a parameter the law lacks reads 0
        cells = []
        for n in names:
            true = measurement_truth(rec, n, channel) if rec.truth else np.nan
            cells.append(f"{true:8.3g}/{values.get(n, 0.0):<8.3g}")
        typer.echo(f"{rec.name:22s} " + " ".join(cells))
    typer.echo(f"\nall fits: {out / 'fits.csv'}")
    if classify:
        _classify(recs, fitted_features)
