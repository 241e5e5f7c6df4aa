"""Where datasets live and how a ``KIND:PATH`` spec becomes a list of recordings.

Every dataset kind yields :class:`~frictionfit.recording.Recording` objects whose
``metadata["label"]`` is the class and whose other metadata keys name the groups
(``session``, ``person``, ``repetition``, ``pressure``, ...).
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path

from frictionfit.errors import DatasetError
from frictionfit.recording import Recording

__all__ = ["DATASET_KINDS", "load_dataset", "shared_dir", "shared_dataset"]

#: Dataset kind -> "module:function" that loads a folder into a list of recordings.
DATASET_KINDS = {
    "recordings": "frictionfit.datasets.rubbing_lab:load",
    "fabricslide": "frictionfit.datasets.fabricslide:load",
    "gesture": "frictionfit.datasets.gesture_skin:load",
}

REPO_ROOT = Path(__file__).resolve().parents[2]


def shared_dir() -> Path | None:
    """The team's ``shared/`` folder: ``$FRICTIONFIT_SHARED``, else ``../shared`` by the repo."""
    env = os.environ.get("FRICTIONFIT_SHARED")
    candidate = Path(env) if env else REPO_ROOT.parent / "shared"
    return candidate if candidate.is_dir() else None


def shared_dataset(name: str) -> Path:
    """Path of ``shared/datasets/<name>``; raises DatasetError saying why it is absent."""
    root = shared_dir()
    if root is None:
        raise DatasetError(
            f"shared datasets not found: expected {REPO_ROOT.parent / 'shared'} "
            "(or set FRICTIONFIT_SHARED)"
        )
    path = root / "datasets" / name
    if not path.is_dir():
        raise DatasetError(f"shared dataset {name!r} not found at {path}")
    return path


def load_dataset(spec: str) -> list[Recording]:
    """Load ``"KIND:PATH"`` (e.g. ``"recordings:data/sample"``) as a list of recordings."""
    kind, sep, path = spec.partition(":")
    if not sep or not path:
        raise DatasetError(
            f"dataset spec {spec!r} must be KIND:PATH, KIND one of {list(DATASET_KINDS)}"
        )
    if kind not in DATASET_KINDS:
        raise DatasetError(f"unknown dataset kind {kind!r}; choose one of {list(DATASET_KINDS)}")
    module, _, func = DATASET_KINDS[kind].partition(":")
    return getattr(importlib.import_module(module), func)(path)
