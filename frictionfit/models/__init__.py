"""Contact models: pure physics, named parameters with units; no files, no solvers.

Importing this package turns on JAX's float64 mode: frictionfit computes in
float64 by default.
"""

import jax

jax.config.update("jax_enable_x64", True)

from frictionfit.models.family import FAMILY as FAMILY  # noqa: E402
from frictionfit.models.family import PARAMS as PARAMS  # noqa: E402
from frictionfit.models.family import ContactModel as ContactModel  # noqa: E402
from frictionfit.models.family import get_model as get_model  # noqa: E402
from frictionfit.models.params import Param as Param  # noqa: E402
from frictionfit.models.stick_slip import contact_force as contact_force  # noqa: E402
from frictionfit.models.stick_slip import drive as drive  # noqa: E402
