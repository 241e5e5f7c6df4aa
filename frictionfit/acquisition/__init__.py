"""Live acquisition: OptoForce frames over pyserial, a lossless recorder, the rubbing protocol.

This layer imports only :mod:`frictionfit.recording` and :mod:`frictionfit.errors`,
and never JAX, so a recorder starts fast and runs beside a fit.
"""
