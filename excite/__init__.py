"""excite: calibration excitation planner for autonomous vehicles."""

from .errors import EvaluationError, ExciteError, LimitError, RigError, RouteError
from .trajectory import GRAVITY, BodySamples, MotionSamples, Trajectory
from .vehicle import ControlProfile, Limits, Suspension, Violation, check_limits, drive

__all__ = [
    "GRAVITY", "BodySamples", "ControlProfile", "EvaluationError", "ExciteError", "LimitError",
    "Limits", "MotionSamples", "RigError", "RouteError", "Suspension", "Trajectory", "Violation",
    "check_limits", "drive",
]
__version__ = "0.1.0"
