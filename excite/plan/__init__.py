"""Plan a calibration maneuver: maximise the score λ_min(S Λ_θ S) over feasible drives.

:func:`optimize` is the whole pipeline as a plain function (no I/O): choose starts among the
reference maneuvers and random candidates, maximise the minimum eigenvalue of the evaluator's
information model (on a coarse copy of the rig: 2 Hz keyframes, 4 IMU samples per interval) with
IPOPT and exact derivatives from CasADi, from several starts at once, re-score the result with the
full evaluator and compare it with the baselines (reference maneuvers, best of N random
candidates, COBYLA).

Modules: :mod:`.problem` (the optimal-control problem, stated apart from how it is solved),
:mod:`.transcription` (its NLP: B-spline controls, multiple shooting, where each constraint is
imposed), :mod:`.kinematics` (control splines → body motion), :mod:`.model` (the information
model in CasADi), :mod:`.compiled` (CasADi functions compiled to C, cached per problem shape),
:mod:`.solver` (IPOPT on the NLP), :mod:`.multistart` (starts on the engine), :mod:`.criteria`,
:mod:`.candidates` (the check and the comparison candidates), :mod:`.baselines` (COBYLA),
:mod:`.pipeline` (the whole run). The CLI (``excite optimize``) and the HTTP service are thin
layers over it.
"""

from __future__ import annotations

from ..errors import OptimizeError
from .settings import OptimizeResult, OptimizeSettings, Progress
from .pipeline import optimize

__all__ = ["OptimizeError", "OptimizeResult", "OptimizeSettings", "Progress", "optimize"]
