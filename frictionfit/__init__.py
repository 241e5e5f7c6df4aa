"""frictionfit: physical contact-model fits and material recognition for tactile rubbing."""

from frictionfit.errors import (
    AcquisitionError as AcquisitionError,
    DatasetError as DatasetError,
    FitError as FitError,
    FrictionfitError as FrictionfitError,
    RecordingError as RecordingError,
    Status as Status,
)
from frictionfit.recording import (
    Channel as Channel,
    Event as Event,
    Recording as Recording,
    read_dataset as read_dataset,
    read_recording as read_recording,
    validate as validate,
    write_recording as write_recording,
)

__version__ = "0.1.0"
