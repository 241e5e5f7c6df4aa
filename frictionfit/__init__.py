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
