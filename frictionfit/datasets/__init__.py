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
    """The team's ``shared/`` folder, or None where it cannot be found.

    ``$FRICTIONFIT_SHARED`` if set; else ``shared/`` beside the source checkout this
    package runs from; else the first ``shared/`` (holding ``datasets/``) beside the
    current folder or one of its parents — so an installed (non-editable) package run
    from inside the repository, or from its ``notebooks/``, still finds ``../shared``.
    """
    env = os.environ.get("FRICTIONFIT_SHARED")
    if env:
        return Path(env) if Path(env).is_dir() else None
    cwd = Path.cwd().resolve()
    for folder in (REPO_ROOT, cwd, *cwd.parents):
        candidate = folder.parent / "shared" if folder == REPO_ROOT else folder / "shared"
        if (candidate / "datasets").is_dir():
            return candidate
    return None


def shared_dataset(name: str) -> Path:
    """Path of ``shared/datasets/<name>``; raises DatasetError saying why it is absent."""
    root = shared_dir()
    if root is None:
        raise DatasetError(
            "shared datasets not found: expected a 'shared/datasets' folder beside the "
            "repository (run from inside it) or FRICTIONFIT_SHARED set to the shared folder"
        )
    path = root / "datasets" / name
    if not path.is_dir():
        raise DatasetError(f"shared dataset {name!r} not found at {path}")
    return path


def load_dataset(spec: str, strict: bool = False) -> list[Recording]:
    """Load ``"KIND:PATH"`` (e.g. ``"recordings:data/sample"``) as a list of recordings.

    A recording that cannot be used is left out with a warning naming it and why
    (:class:`~frictionfit.recording.DatasetWarning`); ``strict=True`` raises instead.
    """
    kind, sep, path = spec.partition(":")
    if not sep or not path:
        raise DatasetError(
            f"dataset spec {spec!r} must be KIND:PATH, KIND one of {list(DATASET_KINDS)}"
        )
    if kind not in DATASET_KINDS:
        raise DatasetError(f"unknown dataset kind {kind!r}; choose one of {list(DATASET_KINDS)}")
    module, _, func = DATASET_KINDS[kind].partition(":")
    return getattr(importlib.import_module(module), func)(path, strict=strict)
