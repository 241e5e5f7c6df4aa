"""Benchmark of feature extraction and classification: speed per recording against error.

Two synthetic workloads (clearly not lab data):

* **gestures**: a simulated textile-skin set (``simulate_gestures``);
  the 270 published features' extraction time (ms per 3-s gesture), the
  quadratic SVM's prediction time (ms per gesture, features given), and the error
  (1 - accuracy) under leave-one-person-out and person-dependent 5-fold;
* **rubbing**: simulated measurements (``simulate_measurements``, several
  sessions); extraction time per measurement of each rubbing feature set (cache
  off) and the error of RBF SVM (one-vs-one) under leave-one-session-out.

Times are medians of interleaved repetitions (:func:`frictionfit.bench.timing.alternate`).
"""

from __future__ import annotations

import tempfile

from sklearn.pipeline import make_pipeline as sk_pipeline
from sklearn.preprocessing import StandardScaler

from frictionfit.bench.timing import alternate, machine_info
from frictionfit.classify import (
    evaluate,
    labels_of,
    make_classifier,
    make_pipeline,
    projection_for,
)
from frictionfit.datasets import load_dataset
from frictionfit.features import make_features
from frictionfit.simulation.gestures import simulate_gestures
from frictionfit.simulation.materials import CLASSES
from frictionfit.simulation.measurements import simulate_measurements

__all__ = ["run"]


def _gestures(quick: bool, seed: int) -> tuple[list[dict], dict]:
    people, reps = (3, 5) if quick else (5, 16)
    with tempfile.TemporaryDirectory() as tmp:
        simulate_gestures(tmp, seed=seed, people=people, repetitions=reps, progress=False)
        recs = load_dataset(f"gesture:{tmp}")
    feats = make_features("gesture").fit(recs)
    x = feats.transform(recs)
    y = labels_of(recs)
    model = sk_pipeline(StandardScaler(), make_classifier("svm-quadratic", seed=seed)).fit(x, y)
    times = alternate({"extract": lambda: feats.transform(recs),
                       "predict": lambda: model.predict(x)}, repeats=1 if quick else 3)
    n = len(recs)
    summary = {
        "n_gestures": n,
        "extract_ms_per_gesture": 1e3 * times["extract"]["median_s"] / n,
        "predict_ms_per_gesture": 1e3 * times["predict"]["median_s"] / n,
    }
    points = []
    for protocol in ("leave-one-person-out", "person-dependent"):
        ev = evaluate(recs, "gesture", "svm-quadratic", protocol, seed=seed)
        summary[f"gesture_accuracy_{protocol}"] = ev.accuracy
        points.append({"config": f"gesture/svm-quadratic/{protocol}",
                       "seconds_per_trial": summary["extract_ms_per_gesture"] / 1e3,
                       "error": 1.0 - ev.accuracy, "error_name": "1 - accuracy"})
    return points, summary


def _rubbing(quick: bool, seed: int) -> tuple[list[dict], dict]:
    classes = CLASSES[:5] if quick else CLASSES[:12]
    sessions, trials = (2, 2) if quick else (3, 4)
    specs = [(s, c, k) for s in range(1, sessions + 1) for c in classes
             for k in range(1, trials + 1)]
    recs = simulate_measurements(specs, seed=seed, pad_to=len(specs))
    sets = {"handcrafted": {}, "fftbins": {}, "physical": {"fitted": not quick}}
    if not quick:
        sets["raw"] = {}
    points, summary = [], {"n_measurements": len(recs)}
    for name, params in sets.items():
        feats = make_features(name, cache=False, **params)
        seconds = alternate({name: lambda f=feats: f.fit_transform(recs)},
                            repeats=1, warmup=False)[name]["median_s"] / len(recs)
        pipe = make_pipeline(name, "svm-ovo", seed=seed, project=projection_for(recs), **params)
        ev = evaluate(recs, protocol="leave-one-session-out", pipeline=pipe, seed=seed)
        config = f"rubbing/{name}{'' if params.get('fitted', True) else '-measured'}/svm-ovo"
        summary[f"{config}/seconds_per_measurement"] = seconds
        summary[f"{config}/accuracy_loso"] = ev.accuracy
        points.append({"config": f"{config}/leave-one-session-out", "seconds_per_trial": seconds,
                       "error": 1.0 - ev.accuracy, "error_name": "1 - accuracy"})
    return points, summary


def run(*, quick: bool = False, seed: int = 0) -> dict:
    """Time feature extraction and prediction, and score the classifiers (synthetic data).

    ``quick=True`` shrinks both workloads (3 people x 5 repetitions of 7 gestures;
    2 sessions x 5 classes x 2 measurements, physical features without fits) so the
    run stays under a minute on an idle two-core machine.
    """
    g_points, g_summary = _gestures(quick, seed)
    r_points, r_summary = _rubbing(quick, seed)
    return {"stage": "classify", "summary": {**g_summary, **r_summary, "quick": quick},
            "points": g_points + r_points, "machine": machine_info()}
