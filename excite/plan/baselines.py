"""The derivative-free baseline: SciPy COBYLA maximising λ_min of the same model.

What open-source calibration planners do: treat the score as a black box. Same decision vector,
same constraints, same coarse information model, same start and the same time budget as the
IPOPT run; λ_min is taken by ``eigvalsh`` (COBYLA needs no derivatives).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
from scipy.optimize import minimize

from .solver import FEASIBLE_TOL, model_value
from .transcription import Transcription, violation
from ..errors import OutOfTime


def cobyla(tr: Transcription, z0: np.ndarray, budget_s: float, criterion: str = "E",
           should_stop: Callable[[], bool] | None = None,
           progress: Callable[[int, float], None] | None = None) -> tuple[np.ndarray | None, float, int]:
    """Best feasible (z, model criterion value, evaluations) COBYLA finds within ``budget_s``."""
    deadline = time.perf_counter() + budget_s
    best = {"z": None, "s": -np.inf, "n": 0}
    z0 = np.asarray(z0, dtype=float)
    lo, hi = tr.lbz, tr.ubz
    scale = max(abs(model_value(tr, z0, "E")), 1e-12) if criterion == "E" else 1.0

    def objective(z):
        if time.perf_counter() > deadline or (should_stop is not None and should_stop()):
            raise OutOfTime
        best["n"] += 1
        s = model_value(tr, z, criterion)
        if s > best["s"] and violation(tr, z, within_limits=True) <= FEASIBLE_TOL:
            best["z"], best["s"] = z.copy(), s
        if progress is not None:
            progress(best["n"], best["s"])
        return -s / scale if np.isfinite(s) else 1e6

    def cons(z):
        g = np.array(tr.g_kin(z)).ravel()
        out = [g - tr.lbg_kin, tr.ubg_kin - g, z - lo, hi - z]
        out = np.concatenate(out)
        return out[np.isfinite(out)]

    try:
        minimize(objective, z0, method="COBYLA", constraints=[{"type": "ineq", "fun": cons}],
                 options={"maxiter": 10**6, "rhobeg": 0.1, "tol": 1e-8})
    except OutOfTime:
        pass
    return best["z"], float(best["s"]), int(best["n"])
