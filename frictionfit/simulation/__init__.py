"""Synthetic data with known truth: single trials, rubbing measurements, gestures, hard cases.

Modules: :mod:`~frictionfit.simulation.trials` (one-channel motions),
:mod:`~frictionfit.simulation.measurements` (whole lab-like measurements with
faults; ``frictionfit simulate``), :mod:`~frictionfit.simulation.materials` (the
35-class material library), :mod:`~frictionfit.simulation.rigs` (the rigs the measurements
are made on; ``frictionfit simulate --rig``), :mod:`~frictionfit.simulation.gestures` (touch
gestures; ``frictionfit simulate gestures``). Nothing here imports JAX until a
force is computed.
"""

from frictionfit.simulation.materials import CLASSES as CLASSES
from frictionfit.simulation.materials import MATERIALS as MATERIALS
from frictionfit.simulation.measurements import simulate_dataset as simulate_dataset
from frictionfit.simulation.measurements import simulate_measurements as simulate_measurements
