"""Live acquisition: OptoForce frames over pyserial, a lossless recorder, the rubbing protocol.

This layer imports only :mod:`frictionfit.recording` and :mod:`frictionfit.errors`,
and never JAX, so a recorder starts fast and runs beside a fit.

- :mod:`~frictionfit.acquisition.frames`: the OptoForce codec (pure, no I/O).
- :mod:`~frictionfit.acquisition.sensor`: one DAQ on a port, handshake, reader thread.
- :mod:`~frictionfit.acquisition.stream`: numbered samples, newtons, reconnection, gaps.
- :mod:`~frictionfit.acquisition.recorder`: incremental fsync'd writer and the record loop.
- :mod:`~frictionfit.acquisition.dynamixel`, :mod:`~frictionfit.acquisition.actuator`:
  Dynamixel Protocol 2.0 codec, the actuator interface, a simulated gripper.
- :mod:`~frictionfit.acquisition.protocol`: the rubbing protocol's schedule, and the
  actuator's position, read between its commands.
"""

from frictionfit.acquisition.actuator import Actuator as Actuator
from frictionfit.acquisition.actuator import DynamixelActuator as DynamixelActuator
from frictionfit.acquisition.actuator import SimulatedGripper as SimulatedGripper
from frictionfit.acquisition.frames import DataFrame as DataFrame
from frictionfit.acquisition.frames import FrameParser as FrameParser
from frictionfit.acquisition.protocol import PositionLog as PositionLog
from frictionfit.acquisition.protocol import ProtocolRunner as ProtocolRunner
from frictionfit.acquisition.protocol import RubbingProtocol as RubbingProtocol
from frictionfit.acquisition.recorder import RecordingWriter as RecordingWriter
from frictionfit.acquisition.recorder import record as record
from frictionfit.acquisition.sensor import OptoForceSensor as OptoForceSensor
from frictionfit.acquisition.sensor import load_sensitivity as load_sensitivity
from frictionfit.acquisition.stream import SensorStream as SensorStream
