"""frictionfit: physical contact-model fits and material recognition for tactile rubbing."""

from frictionfit.errors import (
    AcquisitionError as AcquisitionError,
)
from frictionfit.errors import (
    DatasetError as DatasetError,
)
from frictionfit.errors import (
    FitError as FitError,
)
from frictionfit.errors import (
    FrictionfitError as FrictionfitError,
)
from frictionfit.errors import (
    RecordingError as RecordingError,
)
from frictionfit.errors import (
    Status as Status,
)
from frictionfit.recording import (
    Channel as Channel,
)
from frictionfit.recording import (
    Event as Event,
)
from frictionfit.recording import (
    Recording as Recording,
)
from frictionfit.recording import (
    read_dataset as read_dataset,
)
from frictionfit.recording import (
    read_recording as read_recording,
)
from frictionfit.recording import (
    validate as validate,
)
from frictionfit.recording import (
    write_recording as write_recording,
)

__version__ = "0.1.0"

#: Entry points importable from ``frictionfit`` itself, loaded on first use so that
#: ``import frictionfit`` (and ``frictionfit --help``) never imports JAX.
_LAZY = {
    "segment": "frictionfit.segmentation",
    "fit_recordings": "frictionfit.whole_fit",
    "fit_trials": "frictionfit.fit",
    "fit_report": "frictionfit.fit",
    "sample_posterior": "frictionfit.uncertainty",
    "posterior_summary": "frictionfit.uncertainty",
    "make_features": "frictionfit.features",
    "make_pipeline": "frictionfit.classify",
    "evaluate": "frictionfit.classify",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'frictionfit' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
