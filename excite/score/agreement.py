"""How well a recorded measurement agrees with a drive's motion: the residuals of one rig entry's
recorded measurements against what its kind's model predicts on the drive (a reference pose, a
planned route), at the rig's nominal calibration and after fitting some of the entry's own
coordinates with the motion held.

This is the check a logged drive needs before its score means anything: wheel speeds that
disagree with the pose by more than their noise say the pose, the rig or the time stamps are
wrong. The fit holds the trajectory, so its σ is conditional on it (what the evaluator's
marginal σ is not): a consistency check, not a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import EvaluationError
from ..factors import base as registry
from ..factors import symbolic
from ..factors.base import Nominal
from ..motion.trajectory import Trajectory
from ..rig.config import Rig


@dataclass(frozen=True)
class Agreement:
    """Residuals ``recorded − predicted`` of one entry (rows: factors with a finite recording):
    their RMS per component at the nominal calibration and after the fit, in the measurement's
    units and whitened by the rig's σ; the fitted coordinates' values and σ (conditional on the
    motion, scaled by the whitened residual RMS after the fit)."""

    entry: str
    n_factors: int
    rms_nominal: np.ndarray
    rms_fitted: np.ndarray
    whitened_rms_nominal: float
    whitened_rms_fitted: float
    fitted: dict[str, float]
    fitted_sigma: dict[str, float]
    residuals: np.ndarray  # after the fit, N × components (NaN where not recorded)

    def text(self, labels: list[str] | None = None, unit: str = "") -> str:
        names = labels or [str(i) for i in range(self.rms_nominal.size)]
        at = ", ".join(f"{n} {x:.3g}" for n, x in zip(names, self.rms_nominal))
        after = ", ".join(f"{n} {x:.3g}" for n, x in zip(names, self.rms_fitted))
        fit = "; ".join(f"{k} = {v:.6g} ± {self.fitted_sigma[k]:.2g}" for k, v in self.fitted.items())
        return (f"{self.entry} vs the drive over {self.n_factors} factors: residual RMS{' ' + unit if unit else ''} "
                f"at the nominal calibration {at} (whitened {self.whitened_rms_nominal:.3g}); after fitting "
                f"{', '.join(self.fitted) or 'nothing'}: {after} (whitened {self.whitened_rms_fitted:.3g}){'; ' + fit if fit else ''}")


def agreement(traj: Trajectory, rig: Rig, entry_name: str, recorded: np.ndarray, fit: list[str] = (),
              iterations: int = 4) -> Agreement:
    """The residuals of ``recorded`` (one row per factor of entry ``entry_name`` of ``rig`` on
    ``traj``, in its kind's measurement layout; NaN rows are skipped) against the model, at the
    nominal calibration and after fitting the coordinates ``fit`` (Gauss–Newton on the whitened
    residuals, the motion held)."""
    inst = next((i for i in registry.instances(rig) if i.name == entry_name), None)
    if inst is None:
        names = ", ".join(i.name for i in registry.instances(rig))
        raise EvaluationError(f"rig {rig.name} has no entry {entry_name!r} (entries: {names})")
    unknown = [n for n in fit if n not in [c.name for c in rig.coordinates]]
    if unknown:
        raise EvaluationError(f"cannot fit {', '.join(unknown)}: not coordinates of rig {rig.name}")
    kind, entry = inst.kind, inst.entry
    nom = Nominal.of(traj, rig)
    first = registry.factor_keyframes(kind, rig, entry, nom.n_keyframes)
    recorded = np.asarray(recorded, dtype=float)
    if recorded.shape[0] != first.size:
        raise EvaluationError(f"{entry_name}: {recorded.shape[0]} recorded rows for {first.size} factors on this drive")
    ok = np.all(np.isfinite(recorded), axis=1)
    if not ok.any():
        raise EvaluationError(f"{entry_name}: no recorded row is finite")
    rows = first[ok]
    values = _values(kind, rig, entry)
    lay = symbolic.layout(kind, rig, entry)
    est = [q for q in lay.estimated]
    cols = {n: k for k, n in enumerate(n for q in est for n in q.coordinate_names())}
    sel = [cols[n] for n in fit if n in cols]
    if len(sel) != len(fit):
        raise EvaluationError(f"{entry_name} does not measure {', '.join(n for n in fit if n not in cols)}")

    def whitened(vals):
        return symbolic.residuals(kind, nom, rig, entry, rows, recorded[ok], vals)

    def plain(vals):
        return recorded[ok] - symbolic.measurements(kind, nom, rig, entry, rows, vals)

    r0 = plain(values)
    w0 = whitened(values)
    cov = np.zeros((len(sel), len(sel)))
    for _ in range(iterations if sel else 0):
        blk = symbolic.blocks(kind, nom, rig, entry, values)
        J = blk.Jt[ok][:, :, sel].reshape(-1, len(sel))
        r = whitened(values).ravel()
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        values = _moved(lay, values, dict(zip(sel, step)))
        cov = np.linalg.pinv(J.T @ J)
    w1 = whitened(values)
    r1 = plain(values)
    scale = float(np.sqrt(np.mean(w1 ** 2)))
    fitted = {n: _value_of(lay, values, cols[n]) for n in fit}
    sigma = {n: float(np.sqrt(cov[k, k]) * max(scale, 1.0)) for k, n in enumerate(fit)}
    res = np.full(recorded.shape, np.nan)
    res[ok] = r1
    return Agreement(entry_name, int(ok.sum()), _rms(r0), _rms(r1), float(np.sqrt(np.mean(w0 ** 2))), scale,
                     fitted, sigma, res)


def _rms(r: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(r ** 2, axis=0))


def _values(kind, rig: Rig, entry) -> dict[str, Any]:
    return {q.name: np.array(q.nominal, dtype=float) if np.ndim(q.nominal) else float(q.nominal)
            for q in kind.quantities(rig.config, entry)}


def _moved(lay, values: dict[str, Any], steps: dict[int, float]) -> dict[str, Any]:
    """``values`` with estimated coordinate ``k`` moved by ``steps[k]`` (scalars and vectors
    additively, rotations on the right)."""
    from ..core import so3

    out = dict(values)
    k = 0
    for q in lay.estimated:
        d = np.array([steps.get(k + i, 0.0) for i in range(q.size)])
        if d.any():
            if q.rotation:
                out[q.name] = np.asarray(out[q.name]) @ so3.exp(d[None])[0]
            elif q.size == 3:
                out[q.name] = np.asarray(out[q.name]) + d
            else:
                out[q.name] = float(out[q.name]) + float(d[0])
        k += q.size
    return out


def _value_of(lay, values: dict[str, Any], col: int) -> float:
    k = 0
    for q in lay.estimated:
        if col < k + q.size:
            v = values[q.name]
            if q.rotation:
                from ..core import so3

                return float(so3.log(np.asarray(q.nominal).T @ np.asarray(v))[col - k])
            return float(np.ravel(v)[col - k])
        k += q.size
    raise IndexError(col)
