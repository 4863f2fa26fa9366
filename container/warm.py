"""Build-time warm-up (the Dockerfile runs it as the runtime user, with the runtime environment):
compile and cache the numba kernels that the service's scoring workers use, score the reference
maneuvers of the default optimization problem, and build matplotlib's font cache, so that a new
container loads them instead of compiling (~100 s of CPU in each of its processes here, 189 s
from `podman run` to /healthz).

It runs the very function the app hands its worker pool (``api.app.warm``: bundled rigs, a short
drive scored), so it follows the code wherever that function lives, and streams a short drive
through the live evaluator (what a ``/v1/live`` session's process runs). numba's cache index keys
each kernel by its source file's path and mtime, and the compiled code by the CPU: the cache
written here is valid for the installed files of this image on this machine's CPU model
(``NUMBA_CPU_NAME=generic`` at build and run time makes it valid on any x86-64)."""

import time

t0 = time.perf_counter()
import matplotlib.font_manager  # noqa: E402,F401  (the font list, written to $MPLCONFIGDIR)

import numpy as np  # noqa: E402

from api import app  # noqa: E402
from excite.motion.maneuvers import figure_eight  # noqa: E402
from excite.motion.vehicle import drive  # noqa: E402
from excite.rig.config import load_rig  # noqa: E402
from excite.score.live import PoseStream  # noqa: E402

app.warm()
# a live session's kernels too (a /v1/live session's process runs the incremental evaluator)
rig = load_rig("robotaxi")
t = np.arange(0.0, 30.0, 0.1)
s = drive(figure_eight(duration_s=30.0), rig.suspension).sample(t)
stream = PoseStream(rig)
stream.add(t, s.p_W_V, s.R_W_V)
stream.finish()
# the optimizer's start-up for the service's default problem (robotaxi, 90 s, 80 × 50 m): the
# model compiled in the build stage is found by its key, the reference maneuvers are scored now
# and cached ($EXCITE_CACHE_DIR), so a job of that shape starts at once
from excite.plan import OptimizeSettings  # noqa: E402
from excite.plan.pipeline import prepare  # noqa: E402

done = prepare(rig, OptimizeSettings())
print(f"warm-up: kernels compiled and cached, the optimizer's model {done['mode']}, the reference maneuvers "
      f"{done['references']}, in {time.perf_counter() - t0:.1f} s")
