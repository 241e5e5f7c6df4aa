"""Contact models: pure physics, named parameters with units; no files, no solvers.

Importing this package turns on JAX's float64 mode (frictionfit computes in float64)
and JAX's persistent compilation cache (:func:`frictionfit._system.jax_cache_dir`:
a second process reuses the compiled fits instead of compiling them again;
``FRICTIONFIT_JAX_CACHE=0`` turns it off).
"""

import jax

from frictionfit._system import jax_cache_dir

jax.config.update("jax_enable_x64", True)
if (_cache := jax_cache_dir()) is not None:
    jax.config.update("jax_compilation_cache_dir", str(_cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)

from frictionfit.models.family import FAMILY as FAMILY  # noqa: E402
from frictionfit.models.family import PARAMS as PARAMS  # noqa: E402
from frictionfit.models.family import ContactModel as ContactModel  # noqa: E402
from frictionfit.models.family import get_model as get_model  # noqa: E402
from frictionfit.models.measurement import MeasurementModel as MeasurementModel  # noqa: E402
from frictionfit.models.params import Param as Param  # noqa: E402
from frictionfit.models.stick_slip import contact_force as contact_force  # noqa: E402
from frictionfit.models.stick_slip import drive as drive  # noqa: E402
