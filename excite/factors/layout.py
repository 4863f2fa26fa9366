"""How one factor's inputs are laid out, for the statement (:mod:`.symbolic`), the generator
(:mod:`.generate`) and the generated kernels (:mod:`.kernels`): per keyframe ``[vec R (9,
row-major), p, v, ω, vec R_V_A]`` (27 numbers), the IMU samples of the interval (``n + 1``
orientations and ``n`` specific forces) or their summary, the values of the entry's quantities
(a rotation's 9 entries, a vector's 3, a scalar), the constants its math reads (the kind's, then
:data:`COMMON`); and those inputs made from a nominal motion. numpy only."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import base
from .base import Kind, Nominal, Quantity, ReadsImu, RigView, Variant


KEYFRAME_INPUTS = 27  # vec R (9), p (3), v (3), ω (3), vec R_V_A (9)
# the constants every kind's math may read (besides its own): the factor's interval [s], the IMU's
# sample interval [s] and samples per factor interval, the IMU's pose in V
COMMON: tuple[tuple[str, tuple[int, ...]], ...] = (("dT", ()), ("dt_imu", ()), ("n_imu", ()), ("R_V_B", (3, 3)),
                                                   ("p_V_B", (3,)))


@dataclass(frozen=True)
class Layout:
    """How the inputs of one factor of an entry are laid out (see the module docstring)."""

    kind: str
    variant: Variant
    arity: int
    n_samples: int  # IMU samples per factor interval (0: the kind reads none)
    n_summary: int  # numbers of the summary of an interval's IMU samples (0: the kind reads none)
    n_state: int  # numbers of the fold's state over the samples
    quantities: tuple[Quantity, ...]
    constants: tuple[tuple[str, tuple[int, ...]], ...]  # the kind's, then COMMON

    @property
    def n_state_inputs(self) -> int:
        return KEYFRAME_INPUTS * self.arity

    @property
    def n_sample_inputs(self) -> int:
        return 9 * (self.n_samples + 1) + 3 * self.n_samples if self.n_samples else 0

    @property
    def n_quantity_inputs(self) -> int:
        return sum(q.nominal_vector().size for q in self.quantities)

    @property
    def n_entry_quantities(self) -> int:
        """Numbers of the quantities whose nominal value is the entry's (a kernel's input ``q``)."""
        return sum(q.nominal_vector().size for q in self.quantities if q.per_entry)

    @property
    def n_constants(self) -> int:
        return sum(math.prod(shape) for _, shape in self.constants)

    @property
    def estimated(self) -> list[Quantity]:
        return [q for q in self.quantities if q.estimated]

    @property
    def n_theta(self) -> int:
        return sum(q.size for q in self.estimated)

    @property
    def n_coordinates(self) -> int:
        """Coordinates of every quantity, estimated or not (the columns of a kernel's ``Jt``)."""
        return sum(q.size for q in self.quantities)

    def estimated_columns(self) -> np.ndarray:
        """Which columns of a kernel's ``Jt`` are the estimated coordinates."""
        out, o = [], 0
        for q in self.quantities:
            if q.estimated:
                out += range(o, o + q.size)
            o += q.size
        return np.array(out, dtype=np.int64)

    def name(self, what: str = "lin") -> str:
        """The name of the entry's kernel: ``lin`` (whitened), ``raw`` (rows not whitened),
        ``step`` and ``finish`` (the fold over an interval's IMU samples)."""
        tag = "_".join(str(v) for v in self.variant)
        return f"{what}_{self.kind}" + (f"_{tag}" if tag and what in ("lin", "raw") else "")


def layout(kind: Kind, rig: RigView, entry: Any) -> Layout:
    n = samples_per_keyframe(rig) * base.stride(kind, rig, entry)
    reads = base.implements(kind, ReadsImu)
    consts = tuple((k, np.shape(v)) for k, v in kind.constants(rig, entry).items())
    return Layout(kind.name, base.variant(kind, entry), kind.arity, n if reads else 0,
                  base.summary_size(kind), kind.summary_state if reads else 0,
                  tuple(kind.quantities(rig.config, entry)), consts + COMMON)


def samples_per_keyframe(rig: RigView) -> int:
    return int(round(rig.config.imu.update_rate / rig.keyframe_rate_hz))


def constant_values(kind: Kind, rig: RigView, entry: Any) -> dict[str, np.ndarray]:
    """The constants of ``entry``'s math by name (the kind's, then :data:`COMMON`)."""
    pose = rig.config.vehicle.T_V_B
    dT = base.stride(kind, rig, entry) / rig.keyframe_rate_hz
    common = {"dT": dT, "dt_imu": 1.0 / rig.config.imu.update_rate,
              "n_imu": float(samples_per_keyframe(rig) * base.stride(kind, rig, entry)), "R_V_B": pose.R, "p_V_B": pose.p}
    return {k: np.asarray(v, dtype=float) for k, v in {**kind.constants(rig, entry), **common}.items()}


def constant_inputs(lay: Layout, values: dict[str, np.ndarray]) -> np.ndarray:
    """The constants flat, in the layout's order (matrices row-major)."""
    parts = [np.asarray(values[k], dtype=float).reshape(-1) for k, _ in lay.constants]
    return np.concatenate(parts) if parts else np.zeros(0)


def keyframe_inputs(nom: Nominal, first: np.ndarray, arity: int, stride: int) -> np.ndarray:
    """The per-keyframe inputs of factors starting at keyframes ``first`` (N × 27 · arity)."""
    cols = []
    for a in range(arity):
        k = first + a * stride
        cols += [nom.R[k].reshape(-1, 9), nom.p[k], nom.v[k], nom.omega[k], nom.R_V_A[k].reshape(-1, 9)]
    return np.ascontiguousarray(np.hstack(cols))


def sample_inputs(nom: Nominal, first: np.ndarray, lay: Layout) -> np.ndarray:
    """The IMU samples of the intervals starting at keyframes ``first`` (N × …: the n + 1
    orientations, then the n specific forces)."""
    if not lay.n_samples:
        return np.zeros((first.size, 0))
    n = lay.n_samples
    idx = (first * nom.imu_per_keyframe)[:, None] + np.arange(n + 1)[None, :]
    return np.hstack([nom.imu_R[idx].reshape(first.size, -1), nom.imu_f[idx[:, :n]].reshape(first.size, -1)])


def quantity_inputs(lay: Layout, values: dict[str, Any] | None = None, per_entry: bool = False) -> np.ndarray:
    """The quantities' values, flat: their nominal values, or ``values`` by name where given; of
    those whose nominal value is the entry's only with ``per_entry`` (a kernel's input ``q``)."""
    parts = []
    for q in lay.quantities:
        if per_entry and not q.per_entry:
            continue
        v = q.nominal if values is None or q.name not in values else values[q.name]
        parts.append(np.asarray(v, dtype=float).reshape(-1))
    return np.concatenate(parts) if parts else np.zeros(0)


def coordinate_names(lay: Layout) -> list[str]:
    return [n for q in lay.estimated for n in q.coordinate_names()]


def output_size(lay: Layout, what: str) -> int | None:
    """The size of the first output of the kernel ``what`` (None: it depends on the entry's rows)."""
    return {"step": lay.n_state, "step2": lay.n_state, "finish": lay.n_summary}.get(what)


def input_sizes(lay: Layout, what: str) -> tuple[int, ...]:
    """The sizes of the inputs of the kernel ``what`` of an entry with layout ``lay``."""
    if what == "step":
        return lay.n_state, 9, 9, 3, lay.n_constants
    if what == "step2":
        return lay.n_state, 9, 9, 3, 9, 3, lay.n_constants
    if what == "finish":
        return lay.n_state, 9, 9, lay.n_constants
    return (KEYFRAME_INPUTS,) * lay.arity + (lay.n_summary, lay.n_entry_quantities, lay.n_constants)
