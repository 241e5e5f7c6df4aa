"""Simulated rigs: what lies between the motor and the contact, and the DAQ behind it.

A :class:`SimulatedRig` gives the simulator of :mod:`~frictionfit.simulation.measurements`
its rig: the nominal stroke, the motor's speed, the finger's compliance, the transmission's
play, the printed finger's creep, the sensors' gains and noise, the DAQ's low-pass and
sample rate. The materials are the same on every rig (:mod:`~frictionfit.simulation.materials`),
so what a fit finds that differs between rigs is the rig's, not the material's.

How each effect enters (the contact law is :func:`~frictionfit.models.contact_force`):

- ``finger_k``: a spring (N/mm) in series with the contact's elastic spring: the law runs
  with the series stiffness ``k finger_k / (k + finger_k)``; the truth keeps the material's
  ``k``;
- ``play_mm``: backlash: the finger follows the motor only once the motor has crossed a
  dead band of that width (mm) after each reversal;
- ``creep_mm_per_n`` and ``creep_tau_s``: the finger creeps under the contact force as a
  Kelvin-Voigt element (a displacement ``creep_mm_per_n * F`` reached with time constant
  ``creep_tau_s``), taken off the drive in one correction pass (the force computed once,
  the creep from it, the force again);
- ``gain_scale``, ``noise_scale``: the sensors' gains and noise relative to the default;
- ``lowpass_hz`` (None: none) and ``rate_hz``: the DAQ's second-order
  Butterworth low-pass (causal) and its sample rate, a divisor of the simulator's 1 kHz.

``DEFAULT`` reproduces the simulator without rigs bit for bit (no stroke declared: the
drive's travel is one nominal unit, stiffness per stroke).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DEFAULT", "RIGS", "SimulatedRig", "rig_for"]


@dataclass(frozen=True)
class SimulatedRig:
    """One simulated rig (defaults: the simulator's own rig).

    Attributes
    ----------
    name : str
        Written to ``metadata.rig``.
    stroke_mm : float or None
        Nominal stroke (mm), declared in ``metadata.stroke_mm``; each session's stroke is
        it times 0.9-1.1. None: one nominal unit, not declared.
    motor_speed : float
        The motor's speed relative to the default (movement durations divided by it).
    finger_k : float or None
        Finger and wire stiffness in series with the contact, N/mm (None: rigid).
    play_mm : float
        Width of the transmission's dead band, mm.
    creep_mm_per_n, creep_tau_s : float
        The finger's creep compliance (mm/N) and its time constant (s).
    gain_scale, noise_scale : float
        The sensors' gains and noise relative to the default.
    lowpass_hz : float or None
        Cut-off of the DAQ's second-order Butterworth low-pass (None: none).
    rate_hz : float
        Sample rate; 1000 divided by a whole number.
    """

    name: str = "frictionfit-simulator"
    stroke_mm: float | None = None
    motor_speed: float = 1.0
    finger_k: float | None = None
    play_mm: float = 0.0
    creep_mm_per_n: float = 0.0
    creep_tau_s: float = 0.3
    gain_scale: float = 1.0
    noise_scale: float = 1.0
    lowpass_hz: float | None = None
    rate_hz: float = 1000.0

    def __post_init__(self):
        step = 1000.0 / self.rate_hz
        if self.rate_hz <= 0 or abs(step - round(step)) > 1e-9:
            raise ValueError(f"rig {self.name!r}: rate_hz must divide 1000 Hz (1000, 500, "
                             f"250, ...), not {self.rate_hz}")
        for field in ("motor_speed", "gain_scale", "noise_scale", "creep_tau_s"):
            if not getattr(self, field) > 0:
                raise ValueError(f"rig {self.name!r}: {field} must be > 0")
        if self.stroke_mm is not None and not self.stroke_mm > 0:
            raise ValueError(f"rig {self.name!r}: stroke_mm must be > 0 or None")
        if self.play_mm < 0 or self.creep_mm_per_n < 0:
            raise ValueError(f"rig {self.name!r}: play_mm and creep_mm_per_n must be >= 0")

    @property
    def decimation(self) -> int:
        """Simulator samples (1 kHz) per recorded sample."""
        return round(1000.0 / self.rate_hz)


#: The simulator's own rig (no rig effect; what ``frictionfit simulate`` wrote before rigs).
DEFAULT = SimulatedRig()
#: Three rigs shaped like the lab's (the simulator's materials are in its own mm, so the
#: strokes keep the labs' ratios, 13 : 9 : 16, around the simulator's unit stroke): ``sim-a``
#: a compliant printed finger with play and creep; ``sim-b`` a shorter stroke, a slower motor,
#: a stiffer finger with less play and creep, other sensors, 500 Hz behind a 50 Hz low-pass;
#: ``sim-c`` a longer, faster stroke, a softer finger with more play and creep, 1 kHz.
RIGS: dict[str, SimulatedRig] = {
    "default": DEFAULT,
    "sim-a": SimulatedRig("sim-a", stroke_mm=1.3, finger_k=60.0, play_mm=0.03,
                          creep_mm_per_n=0.01, creep_tau_s=0.3, lowpass_hz=100.0),
    "sim-b": SimulatedRig("sim-b", stroke_mm=0.9, motor_speed=0.7, finger_k=150.0,
                          play_mm=0.01, creep_mm_per_n=0.004, creep_tau_s=0.3, gain_scale=1.3,
                          noise_scale=1.5, lowpass_hz=50.0, rate_hz=500.0),
    "sim-c": SimulatedRig("sim-c", stroke_mm=1.6, motor_speed=1.4, finger_k=40.0,
                          play_mm=0.05, creep_mm_per_n=0.02, creep_tau_s=0.5, gain_scale=0.8,
                          lowpass_hz=120.0),
}


def rig_for(name: str) -> SimulatedRig:
    """The simulated rig called ``name`` (a key of :data:`RIGS`)."""
    try:
        return RIGS[name]
    except KeyError:
        raise ValueError(f"unknown simulated rig {name!r}; choose from {list(RIGS)}") from None
