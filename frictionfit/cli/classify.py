"""``frictionfit features|train|predict|evaluate``: feature tables, models, predictions, scores."""

from __future__ import annotations

from pathlib import Path

import typer

from frictionfit.cli._load import (
    OVERWRITE_HELP,
    STRICT_HELP,
    check_output,
    dataset_reads,
    problems_of,
    stage,
    write_table,
)

DATASET_HELP = "KIND:PATH, e.g. recordings:DIR, fabricslide:DIR or gesture:DIR."
FEATURES_HELP = ("Feature set(s): physical (measured contact quantities), fitted (the contact "
                 "law fitted to each recording), sliding (a FabricSlide slide's texture beyond "
                 "the grip, read through power laws of its stroke shift), handcrafted, fftbins, "
                 "spectral, raw, gesture, touch, shortcut; a comma list concatenates them. "
                 "Default by dataset kind: recordings "
                 "physical,fitted (the most accurate and best calibrated; a fit per "
                 "recording, about 0.15 s each on 2 cores once compiled), fabricslide "
                 "sliding, gesture gesture.")
CLASSIFIER_HELP = "svm-ovo (default), svm-ova, svm-poly, svm-quadratic, knn or mlp."
PROTOCOL_HELP = ("kfold, mixed-5fold, person-dependent, holdout, "
                 "leave-one-{session,person,repetition,pressure,rig}-out "
                 "(rig: metadata.rig; needs recordings of two rigs).")
RELAXATION_HELP = ("Keep the relaxation quantities (fitted relax_frac, tau and drag; measured "
                   "relaxed fraction, relaxation time and curve) in the physical and fitted "
                   "sets. Off by default: how the force relaxes depends on the rig's finger as "
                   "much as on the material, so they do not carry to another rig.")
PROJECT_HELP = ("Projection before the classifier: lda (the linear discriminants, whitened by the "
                "within-class scatter), none, or auto: lda when the data span several sessions.")
#: Figure formats the commands write.
_FIGURES = (".png", ".pdf", ".svg")
#: Metadata columns written beside the features / predictions when present.
GROUP_COLUMNS = ("person", "session", "repetition", "pressure", "speed", "layers", "material")
#: The feature set of each dataset kind when ``--features`` is not given. Rubbing
#: recordings: the quantities read off the force with the fitted law (see docs/results.md
#: for how the sets compare).
DEFAULT_FEATURES = {"recordings": "physical,fitted", "fabricslide": "sliding",
                    "gesture": "gesture"}
#: ``evaluate --all`` defaults per dataset kind: feature sets, protocols.
ALL_DEFAULTS = {
    "recordings": (["physical,fitted", "physical", "handcrafted", "fftbins", "spectral", "raw"],
                   ["kfold", "leave-one-session-out"]),
    "fabricslide": (["sliding", "spectral", "sliding,spectral", "shortcut"],
                    ["leave-one-repetition-out", "leave-one-pressure-out"]),
    "gesture": (["gesture", "touch", "gesture,touch"],
                ["person-dependent", "mixed-5fold", "leave-one-person-out"]),
}


def _load(dataset: str, strict: bool = False):
    from frictionfit.cli._load import load_recordings

    return load_recordings(dataset, strict)


def _fail(message: str, code: int = 1):
    from frictionfit.cli._load import fail

    fail(message, code)


def _features_for(dataset: str, features: str | None) -> str:
    """``--features`` as given, or the dataset kind's :data:`DEFAULT_FEATURES`."""
    return features or DEFAULT_FEATURES.get(dataset.partition(":")[0], "physical")


def _feature_params(relaxation: bool) -> dict:
    """Keyword arguments of the feature sets from the command's flags (none by default)."""
    return {"relaxation": True} if relaxation else {}


def _groups(rec) -> dict:
    return {k: rec.metadata[k] for k in GROUP_COLUMNS if k in rec.metadata}


def features(
    dataset: str = typer.Option(..., help=DATASET_HELP),
    features: str = typer.Option(None, help=FEATURES_HELP, show_default=False),
    out: Path = typer.Option(Path("features.csv"), help="Output table (.csv or .parquet)."),
    relaxation: bool = typer.Option(False, help=RELAXATION_HELP),
    strict: bool = typer.Option(False, help=STRICT_HELP),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Write one row per recording: recording, label, group columns, then the features."""
    import pandas as pd

    from frictionfit.features import make_features

    check_output(out, "--out", (".csv", ".parquet"), overwrite=overwrite,
                 reads=dataset_reads(dataset))
    features = _features_for(dataset, features)
    recordings = _load(dataset, strict)
    try:
        transformer = make_features(features, **_feature_params(relaxation))
        with stage(f"features ({features}) of {len(recordings)} recordings"):
            x = transformer.fit_transform(recordings)
    except (ValueError, ImportError) as exc:
        _fail(str(exc))
    meta = pd.DataFrame([{"recording": r.name, "label": r.label, **_groups(r),
                          "problems": problems_of(r)} for r in recordings])
    table = pd.concat([meta, pd.DataFrame(x, columns=transformer.get_feature_names_out())],
                      axis=1)
    write_table(table, out)
    typer.echo(f"{len(table)} recordings x {x.shape[1]} features -> {out}")


def train(
    dataset: str = typer.Option(..., help=DATASET_HELP),
    features: str = typer.Option(None, help=FEATURES_HELP, show_default=False),
    classifier: str = typer.Option("svm-ovo", help=CLASSIFIER_HELP),
    project: str = typer.Option("auto", help=PROJECT_HELP),
    relaxation: bool = typer.Option(False, help=RELAXATION_HELP),
    out: Path = typer.Option(Path("model.skops"), help="Where to save the model (skops)."),
    seed: int = typer.Option(0, help="Seed of the classifier (MLP, SVM)."),
    calibrate: bool = typer.Option(True, help="Calibrate the class probabilities on "
                                   "held-out training recordings."),
    draws: int = typer.Option(32, min=0, help="With --calibrate: average the probabilities "
                              "over this many feature draws per recording (0: point values)."),
    strict: bool = typer.Option(False, help=STRICT_HELP),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Train features -> (session standardisation) -> scaler -> (projection) -> classifier.

    The model is saved with skops (loading it runs no code), with what it was trained
    on: feature set, dataset kind, channels, classes and rigs (metadata.rig, the declared
    stroke, the sample rate). Calibrated, its probabilities on another rig are tempered by
    the spread between the training rigs (between sessions where there is one rig)."""
    from frictionfit.calibration import CalibratedPipeline
    from frictionfit.classify import classes_of, make_pipeline, projection_for
    from frictionfit.errors import FrictionfitError
    from frictionfit.model_file import save_model
    from frictionfit.transfer import RigTransfer, rigs_of

    check_output(out, "--out", (".skops",), overwrite=overwrite, reads=dataset_reads(dataset))
    features = _features_for(dataset, features)
    recordings = _load(dataset, strict)
    try:
        y = classes_of(recordings)
        pipeline = make_pipeline(features, classifier, seed=seed,
                                 project=projection_for(recordings, _projection(project)),
                                 probability=calibrate, **_feature_params(relaxation))
        model = (RigTransfer(CalibratedPipeline(pipeline, n_draws=draws, seed=seed))
                 if calibrate else pipeline)
        with stage(f"training on {len(recordings)} recordings ({features})"):
            model.fit(recordings, y)
    except (FrictionfitError, ValueError, ImportError) as exc:
        _fail(str(exc))
    fitted = model.model_.pipeline_ if calibrate else model
    save_model({
        "pipeline": model,
        "features": features,
        "relaxation": relaxation,
        "classifier": classifier,
        "project": "lda" if "project" in fitted.named_steps else "none",
        "feature_names": list(fitted["features"].get_feature_names_out()),
        "labels": sorted(map(str, set(y))),
        "dataset_kind": dataset.partition(":")[0],
        "channels": [[c.name, c.unit] for c in recordings[0].channels],
        "sample_rates_hz": sorted({float(r.sample_rate_hz) for r in recordings}),
        "n_train": len(recordings),
        "rigs": rigs_of(recordings),
        "frictionfit_version": _version(),
    }, out)
    typer.echo(f"trained {features} + {classifier} on {len(recordings)} recordings "
               f"({len(set(y))} classes) -> {out}")


def _projection(name: str) -> str | None:
    """The ``--project`` name as ``projection_for`` takes it (which refuses unknown names)."""
    return None if name == "none" else name


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("frictionfit")
    except metadata.PackageNotFoundError:
        return "unknown"


def predict(
    model: Path = typer.Argument(..., help="A model saved by `frictionfit train`."),
    dataset: str = typer.Option(..., help=DATASET_HELP),
    out: Path = typer.Option(Path("predictions.csv"), help="Output table (.csv)."),
    abstain: float = typer.Option(0.0, min=0.0, max=1.0, help="Write 'abstain' as the "
                                  "prediction where the top probability is below this."),
    strict: bool = typer.Option(False, help=STRICT_HELP),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Write recording, predicted, probability, true label and the top-3 classes.

    Probabilities are calibrated (models trained with --calibrate, the default):
    'probability' is that of the predicted class ('abstain' where it is below
    --abstain); top1..3 are the most probable classes.
    """
    import numpy as np
    import pandas as pd

    from frictionfit.calibration import top_classes
    from frictionfit.errors import ModelError
    from frictionfit.model_file import load_model

    check_output(out, "--out", (".csv",), overwrite=overwrite,
                 reads=[model, *dataset_reads(dataset)])
    try:
        saved = load_model(model)
    except ModelError as exc:
        _fail(str(exc))
    pipeline = saved["pipeline"]
    kind = dataset.partition(":")[0]
    if saved.get("dataset_kind") not in (None, kind):
        _fail(f"{model} was trained on {saved['dataset_kind']!r} recordings "
              f"({saved['features']} features), not {kind!r}")
    recordings = _load(dataset, strict)
    _check_channels(saved, model, recordings)
    _say_rigs(saved, model, recordings)
    other_rate = _other_rates(saved, model, recordings)
    try:
        with stage(f"predicting {len(recordings)} recordings ({saved['features']})"):
            predicted = pipeline.predict(recordings)
            proba = pipeline.predict_proba(recordings) if hasattr(pipeline, "predict_proba") \
                else None
    except (ValueError, ImportError) as exc:
        _fail(str(exc))
    table = pd.DataFrame({"recording": [r.name for r in recordings], "predicted": predicted})
    top = None
    if proba is not None:
        classes = list(map(str, pipeline.classes_))
        called = [classes.index(str(p)) for p in predicted]
        table["probability"] = proba[np.arange(len(table)), called]
        top = top_classes(proba, pipeline.classes_)
        if abstain > 0:
            table["predicted"] = np.where(table["probability"] < abstain, "abstain",
                                          table["predicted"].astype(object))
    labels = [r.label for r in recordings]
    if all(lab is not None for lab in labels):
        table["true"] = labels
        unseen = sorted({str(lab) for lab in labels} - set(saved.get("labels", [])))
        if unseen:
            typer.echo(f"{sum(str(lab) in unseen for lab in labels)} recording(s) of classes "
                       f"the model never saw in training: {unseen} (counted wrong below)",
                       err=True)
    if top is not None:
        table = pd.concat([table, top], axis=1)
    if hasattr(pipeline, "seen"):
        table["rig_seen"] = pipeline.seen(recordings)
    table["problems"] = ["; ".join(filter(None, (problems_of(r), other_rate.get(r.name, ""))))
                         for r in recordings]
    table.to_csv(out, index=False)
    typer.echo(f"{len(table)} predictions -> {out}")
    if "true" in table:
        _say_scores(table, abstain)


def _say_scores(table, abstain: float) -> None:
    """Print, for the decided calls of a predictions ``table`` with true labels, their ECE
    beside a calibrated classifier's on as many (with probabilities), then the accuracy."""
    import numpy as np

    from frictionfit.calibration import ECE_BINS, calibrated_ece, expected_calibration_error

    decided = (table["predicted"].astype(str) != "abstain").to_numpy()
    right = (table["true"].astype(str) == table["predicted"].astype(str)).to_numpy()[decided]
    if not decided.all():
        typer.echo(f"abstained on {int((~decided).sum())} of {len(table)} recordings "
                   f"(top probability below {abstain:g}); accuracy over the "
                   f"{int(decided.sum())} decided")
    if "probability" in table and right.size:
        conf = table["probability"].to_numpy()[decided]
        ece, (median, high) = expected_calibration_error(conf, right), calibrated_ece(conf)
        typer.echo(f"expected calibration error ({ECE_BINS} bins): {ece:.3f}; a calibrated "
                   f"classifier's at these probabilities on {right.size} recordings: "
                   f"{median:.3f} (95 %: {high:.3f})")
    typer.echo(f"accuracy: {float(np.mean(right)) if right.size else 0.0:.3f}")


def _say_rigs(saved: dict, model: Path, recordings: list) -> None:
    """Say on stderr which recordings are of a rig ``model`` was not trained on, what
    differs, and how their probabilities are tempered."""
    from frictionfit.transfer import describe_rig, unseen_rigs

    trained = saved.get("rigs")
    if trained is None:
        typer.echo(f"{model} does not record the rigs it was trained on (trained before "
                   "models did): its probabilities assume the training rig", err=True)
        return
    notes = unseen_rigs(trained, recordings)
    for note in notes:
        typer.echo(f"{note} (the 'problems' column names each recording)", err=True)
    if notes:
        pipeline = saved["pipeline"]
        beta = getattr(pipeline, "shift_beta_", None)
        typer.echo(f"trained on {', '.join(describe_rig(r) for r in trained)}; "
                   + (f"their probabilities are tempered (log-probabilities x {beta:.3g}, "
                      f"from held-out {pipeline.shift_groups_}s of the training data)"
                      if beta is not None else "their probabilities are not tempered "
                      "(an uncalibrated model)"), err=True)


def _check_channels(saved: dict, model: Path, recordings: list) -> None:
    """Stop when a recording lacks a channel (name and unit) the model was trained on,
    naming the recording, the channels and the model file."""
    want = [tuple(c) for c in saved.get("channels", [])]
    for rec in recordings:
        have = [(c.name, c.unit) for c in rec.channels]
        if want and not set(want) <= set(have):
            missing = [f"{n} [{u}]" for n, u in want if (n, u) not in have][:4]
            _fail(f"{rec.name}: channels {missing} that {model} was trained on are missing "
                  f"(it has {[f'{n} [{u}]' for n, u in have][:6]})")


def _other_rates(saved: dict, model: Path, recordings: list) -> dict[str, str]:
    """Recordings at a sample rate the model was not trained at, for the 'problems' column:
    name -> ``[other_rate] ...`` (empty for a model file that does not record its rates).
    Stderr's rig line (:func:`_say_rigs`) says it once per rig."""
    rates = saved.get("sample_rates_hz")
    if not rates:
        return {}
    trained = ", ".join(f"{r:g}" for r in rates)
    return {r.name: f"[other_rate] recorded at {r.sample_rate_hz:g} Hz; {model.name} was "
                    f"trained at {trained} Hz: its features, and so the probabilities, may differ"
            for r in recordings if not any(abs(r.sample_rate_hz / x - 1) < 1e-6 for x in rates)}


def evaluate(
    dataset: str = typer.Option(..., help=DATASET_HELP),
    features: str = typer.Option(None, help=FEATURES_HELP, show_default=False),
    classifier: str = typer.Option("svm-ovo", help=CLASSIFIER_HELP),
    protocol: str = typer.Option("kfold", help=PROTOCOL_HELP),
    project: str = typer.Option("auto", help=PROJECT_HELP),
    relaxation: bool = typer.Option(False, help=RELAXATION_HELP),
    target: str = typer.Option("label", help="Metadata key to predict, e.g. layers."),
    out: Path = typer.Option(None, help="Save the scores (.csv)."),
    confusion: Path = typer.Option(None, help="Save the confusion matrix (.png)."),
    reliability: Path = typer.Option(None, help="Save the reliability diagram and the "
                                     "accuracy against coverage (.png)."),
    predictions: Path = typer.Option(None, help="Save every test recording's prediction, "
                                     "probability and top-3 classes (.csv)."),
    calibrate: bool = typer.Option(True, help="Calibrated class probabilities (held-out "
                                   "training recordings)."),
    draws: int = typer.Option(32, min=0, help="With --calibrate: average the probabilities "
                              "over this many feature draws per recording (0: point values)."),
    all_: bool = typer.Option(False, "--all", help="Every feature set x classifier x protocol "
                              "(defaults per dataset kind; or the --feature-sets, "
                              "--classifiers, --protocols lists)."),
    feature_sets: str = typer.Option(None, help="With --all: feature sets, ';'-separated."),
    classifiers: str = typer.Option(None, help="With --all: classifiers, comma-separated."),
    protocols: str = typer.Option(None, help="Protocols, comma-separated: with --all, those "
                                  "combined; without, each run with --features and "
                                  "--classifier. A leave-one-X-out protocol also reports "
                                  "each left-out value of X (e.g. pressure) on its own."),
    seed: int = typer.Option(0, help="Seed of the splits and classifiers."),
    results: Path = typer.Option(None, help="Also add the scores, dated, to this results file "
                                 "(e.g. docs/results.md)."),
    strict: bool = typer.Option(False, help=STRICT_HELP),
    overwrite: bool = typer.Option(False, help=OVERWRITE_HELP),
) -> None:
    """Train and test under a protocol; print accuracy and macro-F1 (last line: accuracy)."""
    import pandas as pd

    from frictionfit.classify import projection_for

    reads = dataset_reads(dataset)
    for path, option, suffixes in ((out, "--out", (".csv",)),
                                   (confusion, "--confusion", _FIGURES),
                                   (reliability, "--reliability", _FIGURES),
                                   (predictions, "--predictions", (".csv",))):
        check_output(path, option, suffixes, overwrite=overwrite, reads=reads)
    check_output(results, "--results", (".md",), reads=reads, replaces=False)
    features = _features_for(dataset, features)
    recordings = _load(dataset, strict)
    try:
        projection = projection_for(recordings, _projection(project))
    except ValueError as exc:
        _fail(str(exc))
    combos = (_all_combos(dataset, feature_sets, classifiers, protocols) if all_
              else [(features, classifier, p) for p in (protocols or protocol).split(",")])
    typer.echo(f"projection before the classifier: {projection or 'none'}")
    rows, ev = _score(recordings, combos, all_, target=target, seed=seed, project=projection,
                      calibrate=calibrate, n_draws=draws,
                      feature_params=_feature_params(relaxation))
    if not rows:
        _fail("no combination could be evaluated")
    table = pd.DataFrame(rows)
    if out is not None:
        table.to_csv(out, index=False)
        typer.echo(f"scores -> {out}")
    if results is not None:
        from frictionfit.bench.report import frame_markdown, record_results

        lists = (("--feature-sets", feature_sets), ("--classifiers", classifiers),
                 ("--protocols", protocols))
        record_results(results, f"frictionfit evaluate --dataset {dataset}"
                       + (" --all" + "".join(f' {o} "{v}"' for o, v in lists if v) if all_
                          else f" --features {features} --classifier {classifier} --protocol "
                          f"{protocol}"),
                       frame_markdown(table))
        typer.echo(f"added the scores to {results}")
    if not all_:
        _evaluation_files(ev, f"{features} / {classifier} / {protocol}", confusion,
                          predictions, reliability)
        typer.echo(f"macro-F1: {ev.macro_f1:.3f}")
        typer.echo(f"accuracy: {ev.accuracy:.3f}")


def _all_combos(dataset: str, feature_sets: str | None, classifiers: str | None,
                protocols: str | None) -> list[tuple[str, str, str]]:
    """``evaluate --all``: every feature set x classifier x protocol of the lists given, or of
    the dataset kind's :data:`ALL_DEFAULTS` and every classifier."""
    from frictionfit.classify import CLASSIFIERS

    kind = dataset.partition(":")[0]
    default_sets, default_protocols = ALL_DEFAULTS.get(kind, ALL_DEFAULTS["recordings"])
    return [(f, c, p)
            for f in (feature_sets.split(";") if feature_sets else default_sets)
            for c in (classifiers.split(",") if classifiers else CLASSIFIERS)
            for p in (protocols.split(",") if protocols else default_protocols)]


def _score(recordings: list, combos: list[tuple[str, str, str]], skip_failed: bool, **kw):
    """Evaluate each ``(features, classifier, protocol)`` (``kw``: to
    :func:`frictionfit.classify.evaluate`) and print its scores; one that fails stops the
    command, or is skipped with a note (``skip_failed``). The score rows and the last
    evaluation."""
    from frictionfit.classify import evaluate as run
    from frictionfit.errors import FrictionfitError

    rows, ev = [], None
    for f, c, p in combos:
        try:
            ev = run(recordings, f, c, p, **kw)
        except (FrictionfitError, ValueError, ImportError) as exc:
            if not skip_failed:
                _fail(str(exc))
            typer.echo(f"skipped {f} / {c} / {p}: {exc}", err=True)
            continue
        scores = ev.calibration()
        rows.append({"features": f, "classifier": c, "protocol": p,
                     "accuracy": ev.accuracy, "macro_f1": ev.macro_f1, **scores})
        shown = "".join(f"  {k} {v:.3f}" for k, v in scores.items())
        typer.echo(f"{f:>20} {c:>14} {p:>26}  accuracy {ev.accuracy:.3f}  "
                   f"macro-F1 {ev.macro_f1:.3f}{shown}")
        _print_left_out(ev, p)
    return rows, ev


def _print_left_out(ev, protocol: str) -> None:
    """A leave-one-X-out protocol's accuracy per left-out value of X, one per line, with
    where it lies against the training values."""
    from frictionfit.classify import CONDITIONS, left_out_scores

    key = protocol.removeprefix("leave-one-").removesuffix("-out")
    if not protocol.startswith("leave-one-") or key not in CONDITIONS:
        return
    for row in left_out_scores(ev, key).to_dict("records"):
        where = f", {row['where']} the training {key}s" if row["where"] else ""
        typer.echo(f"{'':>20} left out {key} {row[key]} (trained on {row['trained_on']}"
                   f"{where}): accuracy {row['accuracy']:.3f} (n {row['n']})")


def _evaluation_files(ev, title: str, confusion: Path | None, predictions: Path | None,
                      reliability: Path | None) -> None:
    """The files asked for of one evaluation: confusion matrix, predictions and (with
    probabilities) the reliability diagram."""
    if confusion is not None:
        _plot_confusion(ev.confusion, confusion, title)
        typer.echo(f"confusion matrix -> {confusion}")
    if predictions is not None:
        ev.predictions.to_csv(predictions, index=False)
        typer.echo(f"predictions -> {predictions}")
    if reliability is not None and "probability" in ev.predictions:
        from frictionfit.calibration import plot_reliability

        plot_reliability(ev.predictions["probability"], ev.correct, reliability, title)
        typer.echo(f"reliability diagram -> {reliability}")


def _plot_confusion(matrix, path: Path, title: str) -> None:
    from frictionfit._optional import pyplot

    plt = pyplot("The confusion matrix PNG")
    from sklearn.metrics import ConfusionMatrixDisplay

    n = len(matrix)
    fig, ax = plt.subplots(figsize=(max(4.0, 0.3 * n + 2), max(4.0, 0.3 * n + 2)))
    ConfusionMatrixDisplay(matrix.to_numpy(), display_labels=list(matrix.index)).plot(
        ax=ax, colorbar=False, include_values=n <= 12, xticks_rotation="vertical")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
