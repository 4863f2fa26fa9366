"""The optimizer's comparison worker is ended in every state it can be in (starting, scoring the
references, screening, running COBYLA, sending a result) and the process that used it exits: the
path that once left `excite optimize` waiting forever, after printing its result, on a thread
reading the pipe of a worker terminated mid-write."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

CLOSE_MANY = """
import random, time
import numpy as np
from excite.plan import OptimizeSettings
from excite.plan.pipeline import _Worker
from excite.plan.site import read_site
from excite.rig.config import load_rig

rig = load_rig("robotaxi")
settings = OptimizeSettings(duration_s=30.0, lot_x_m=60.0, lot_y_m=40.0, n_random=10, time_budget_s=5.0).for_rig(rig)
random.seed({seed})
for i in range({rounds}):
    w = _Worker(rig, settings, settings.lot, refs=True)
    if random.random() < 0.8:
        w.start_rest(np.zeros(4), 1.0, settings.n_random, [])
    time.sleep(random.choice([0.0, 0.05, 0.3, 1.0, 2.0, 3.0]))
    if random.random() < 0.5:
        w.collect(time.monotonic() + random.uniform(0, 0.5), time.monotonic() + random.uniform(0, 0.5))
    w.close()
last = _Worker(rig, settings, settings.lot, refs=True)  # one left working when the interpreter exits
last.start_rest(np.zeros(4), 1.0, settings.n_random, [])
print("done", flush=True)
"""


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_the_comparison_worker_ended_in_any_state_leaves_nothing_to_wait_for(seed):
    rounds = 10
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", CLOSE_MANY.format(seed=seed, rounds=rounds)],
                       env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True,
                       timeout=240)
    assert r.returncode == 0 and r.stdout.strip() == "done", r.stderr[-3000:]
    assert time.monotonic() - t0 < 240
