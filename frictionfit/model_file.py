"""Trained models on disk, in a format whose loading runs no code (``skops.io``).

A model file holds the fitted pipeline and what it was trained on (feature set,
dataset kind, channels with units, classes, and the rigs: ``rigs``, one entry per rig of
:func:`frictionfit.transfer.rigs_of`, with its declared stroke and sample rate).
:func:`load_model` refuses a file that holds any type outside :func:`trusted_types`
(frictionfit's estimators and feature sets, and the scikit-learn parts skops does not
trust by default), naming the file and the types: unpickling an untrusted file could run its code.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

from frictionfit._types import PathType
from frictionfit.errors import ModelError

__all__ = ["load_model", "save_model", "trusted_types"]

#: scikit-learn internals of calibrated classifiers (not trusted by skops by default).
_SKLEARN_TRUSTED = (
    "sklearn.calibration._CalibratedClassifier",
    "sklearn.calibration._TemperatureScaling",
    "sklearn.calibration._SigmoidCalibration",
)


def trusted_types() -> list[str]:
    """Types a frictionfit model file may hold beyond skops' defaults."""
    from frictionfit.features import FEATURE_SETS

    ours = [spec.replace(":", ".") for spec in FEATURE_SETS.values()]
    return sorted({
        *ours,
        "frictionfit.features.sliding.SlidingPhysicalFeatures",
        "frictionfit.features.grip.GripLaw",
        "frictionfit.classify.DiscriminantProjection",
        "frictionfit.classify.SessionNormalised",
        "frictionfit.calibration.CalibratedPipeline",
        "frictionfit.calibration._Scores",
        "frictionfit.calibration._Temperature",
        "frictionfit.transfer.RigTransfer",
        *_SKLEARN_TRUSTED,
    })


def save_model(payload: dict[str, Any], path: PathType) -> Path:
    """Write ``payload`` (``pipeline`` plus what it was trained on) to ``path`` (.skops)."""
    import skops.io

    path = Path(path)
    skops.io.dump(payload, path)
    return path


def load_model(path: PathType) -> dict[str, Any]:
    """Read a model written by :func:`save_model`; :class:`~frictionfit.errors.ModelError`
    naming the file when it is missing, damaged, not a model, or holds untrusted types."""
    import skops.io

    path = Path(path)
    if not path.is_file():
        raise ModelError("model file not found", path=path)
    if path.stat().st_size == 0:
        raise ModelError("the model file is empty", path=path)
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as f:
            if f.read(4) == b"PK\x03\x04":  # a zip's start without its end: cut short
                raise ModelError("damaged: the model file is cut short (truncated while it was "
                                 "written or copied?); copy it again or retrain", path=path)
        hint = (" (a pickle/joblib file from an older frictionfit: retrain it, since loading "
                "a pickle can run any code)" if path.suffix in (".joblib", ".pkl") else "")
        raise ModelError(f"not a model written by `frictionfit train`{hint}", path=path)
    try:
        untrusted = set(skops.io.get_untrusted_types(file=path)) - set(trusted_types())
        if untrusted:
            raise ModelError(f"refused: the file holds types frictionfit does not trust "
                             f"{sorted(untrusted)} (loading them could run code)", path=path)
        payload = skops.io.load(path, trusted=trusted_types())
    except (zipfile.BadZipFile, KeyError, ValueError, TypeError, EOFError) as exc:
        raise ModelError(f"damaged or not a model written by `frictionfit train`: {exc}",
                         path=path) from None
    if not isinstance(payload, dict) or not hasattr(payload.get("pipeline"), "predict"):
        raise ModelError("not a model written by `frictionfit train`", path=path)
    return payload
