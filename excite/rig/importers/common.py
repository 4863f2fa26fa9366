"""What every importer shares: matrices and rotations to the precision of their printed digits
(the files are read by :mod:`excite.rig.files`), sensor names from frames, the defaults for what
a file cannot tell (each marked for review), and the rig YAML an import writes.

**Rotations.** A matrix read from a file is a rotation as far as its printed digits tell: each
entry printed with d decimals is off by at most ½·10⁻ᵈ, so the nearest rotation R̂ (polar
decomposition) lies within ``tol = √Σ(½·10^-d_ij)²`` of it in the Frobenius norm. Entries printed
as exactly 0 or ±1 are taken at the coarsest precision of the others (a writer drops trailing
zeros). Within ``tol`` (plus 1e-12 for the arithmetic of whoever computed it) the matrix is
replaced by R̂ and the correction is reported; beyond it the file is refused, naming the
deviation and the tolerance. A reflection (det −1) is refused.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ...errors import RigError
from ...factors.gnss import PRESETS
from ..config import RigConfig, body_axes, build_rig
# what the importers read files with, one name away
from ..files import OpenCVMatrix, OpenCVTag, find_key, load_yaml, mapping, number, read_text  # noqa: F401

MAX_FRAMES = 4096  # frames of a tree (a robot's URDF has a few hundred links at most)
ARITHMETIC_TOL = 1e-12  # what a rotation computed in double precision may be off by

# A consumer MEMS IMU (datasheet class of a BMI088 / ICM-42688), Kalibr keys and units.
DEFAULT_IMU = {"accelerometer_noise_density": 2.0e-3, "accelerometer_random_walk": 3.0e-4,
               "gyroscope_noise_density": 1.7e-4, "gyroscope_random_walk": 2.0e-5,
               "update_rate": 200.0}
# Drift densities of lidar and camera odometry when the file gives none: 0.1 deg and 1 cm per
# frame pair at 10 Hz (σ·√10); the rig guide gives measured values per sensor class.
DEFAULT_ODOMETRY_NOISE = {"rotation_density_deg_per_sqrt_s": 0.316,
                          "translation_density_m_per_sqrt_s": 0.0316}
DEFAULT_RATE_HZ = 10.0
DEFAULT_GNSS_PRESET = "standalone"

HIGHWAY_SPEED_MPS = 20.0  # the speed at which a GNSS time offset's default target is set


def default_targets(sensors: list[dict[str, Any]]) -> dict[str, str]:
    """Accuracy targets for an imported rig, per kind, that its sensors' noise can reach.

    Lidars and cameras: 0.1 deg, 1 cm, 2 ms. IMU biases: 0.01 deg/s, 0.02 m/s². A GNSS antenna's
    lever arm: half its fix's horizontal σ (known to half the fix's σ, it adds at most 12 % to
    the error of a position fused from the fixes: √(1 + ¼)), and its time offset the time in
    which a car at 20 m/s travels that far (1 cm and 0.5 ms with RTK, 0.75 m and 38 ms
    standalone): a standalone antenna does not get the 1 cm an RTK antenna needs."""
    out: dict[str, str] = {}
    kinds = {s["kind"] for s in sensors}
    if kinds & {"lidar", "camera"}:
        out["*.rot_*"] = "0.1 deg"
        out["*.trans_*"] = "1 cm"
        out["*.time_offset"] = "2 ms"
    for s in sensors:
        if s["kind"] == "gnss":
            sigma = float(_gnss_noise(s["noise"])["horizontal_sigma_m"]) / 2.0
            out[f"{s['name']}.trans_*"] = _quantity(sigma, "m")
            out[f"{s['name']}.time_offset"] = _quantity(sigma / HIGHWAY_SPEED_MPS, "s")
    out["imu.gyro_bias_*"] = "0.01 deg/s"
    out["imu.accel_bias_*"] = "0.02 m/s^2"
    return out


def _gnss_noise(noise: Any) -> dict[str, Any]:
    if isinstance(noise, str):
        return PRESETS[noise]
    if "preset" in noise:
        return {**PRESETS[noise["preset"]], **{k: v for k, v in noise.items() if k != "preset"}}
    return noise


def _quantity(x: float, unit: str) -> str:
    if unit == "m":
        return f"{x * 100:.3g} cm" if x < 1.0 else f"{x:.3g} m"
    return f"{x * 1000:.3g} ms"


# --------------------------------------------------------------------------------------------
# The imported rig


@dataclass
class ImportedRig:
    """A rig config (plain data, ready for YAML), what in it the source could not tell
    (``review``: dotted key → why), and notes for the header (sources, what was read)."""

    config: dict[str, Any]
    review: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def review_lines(self) -> list[str]:
        """The keys to review, for the import's message: a sensor key shared by several sensors
        for the same reason is one line naming them."""
        groups: dict[tuple[str, str], list[str]] = {}
        for key, why in self.review.items():
            m = re.fullmatch(r"sensors\.(\d+)\.(.+)", key)
            if m:
                name = self.config["sensors"][int(m.group(1))]["name"]
                groups.setdefault((m.group(2), why), []).append(name)
            else:
                groups.setdefault((key, why), [])
        return [f"{field} of {', '.join(names)}: {why}" if names else f"{field}: {why}"
                for (field, why), names in groups.items()]


def finish(cfg: dict[str, Any], review: dict[str, str], notes: list[str], source: str | Path) -> ImportedRig:
    """The imported rig, validated as any rig is (a problem names the source file)."""
    try:
        rig = build_rig(cfg)
    except RigError as exc:
        raise RigError(f"{source}: the imported rig is not valid: {exc}") from None
    notes = notes + [frame_note(rig.config)]
    return ImportedRig(cfg, review, notes)


def frame_note(cfg: RigConfig) -> str:
    """Where ``trans_*`` is: the sensors' positions in the IMU frame B, whose axes in the vehicle
    frame V are read off ``T_V_B``."""
    return (f"trans_* (each T_B_S translation) is the sensor's position in the IMU frame B, whose axes "
            f"point {body_axes(cfg.vehicle.T_V_B.R)} of the vehicle frame (T_V_B)")


def pose(R: np.ndarray, p: np.ndarray) -> dict[str, Any]:
    """A rig Pose: translation and the rotation matrix (exact; rpy would round)."""
    return {"translation_m": [float(x) + 0.0 for x in np.round(p, 12)],  # +0.0: no -0.0
            "matrix": [[float(x) for x in row] for row in R]}


def invert(R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return R.T, -R.T @ p


def odometry_sensor(name: str, kind: str, R: np.ndarray, p: np.ndarray, review: dict[str, str], index: int, *,
                    rate_hz: float | None = None, rate_from: str = "", monocular: bool | None = None,
                    monocular_why: str = "") -> dict[str, Any]:
    """A lidar or camera entry; what its source does not tell (rate, noise, a camera's
    monocular) gets its default and a line in ``review``."""
    key = f"sensors.{index}"
    entry: dict[str, Any] = {"name": name, "kind": kind}
    if rate_hz is None:
        entry["rate_hz"] = DEFAULT_RATE_HZ
        review[f"{key}.rate_hz"] = f"not in the file{rate_from}: {DEFAULT_RATE_HZ:g} Hz assumed"
    else:
        entry["rate_hz"] = float(rate_hz)
    if kind == "camera":
        entry["monocular"] = True if monocular is None else monocular
        review[f"{key}.monocular"] = monocular_why or (
            "whether its odometry has a metric scale is not in the file: monocular (scale a nuisance of "
            "each drive) assumed; set false for a stereo or depth odometry")
    entry["T_B_S"] = pose(R, p)
    entry["noise"] = dict(DEFAULT_ODOMETRY_NOISE)
    review[f"{key}.noise"] = ("odometry drift densities are not in the file: defaults (see the rig guide, "
                              "or measure them: excite rig noise)")
    return entry


def gnss_sensor(name: str, p: np.ndarray, review: dict[str, str], index: int) -> dict[str, Any]:
    review[f"sensors.{index}.noise"] = (f"the receiver is not in the file: preset {DEFAULT_GNSS_PRESET!r} "
                                        "assumed (rtk for an RTK fix)")
    review[f"sensors.{index}.rate_hz"] = f"not in the file: {DEFAULT_RATE_HZ:g} Hz assumed"
    return {"name": name, "kind": "gnss", "rate_hz": DEFAULT_RATE_HZ,
            "T_B_S": {"translation_m": [float(x) for x in p]}, "noise": DEFAULT_GNSS_PRESET}


def default_imu(review: dict[str, str], why: str = "no IMU noise in the file") -> dict[str, float]:
    review["imu"] = f"{why}: a consumer MEMS IMU's densities and 200 Hz assumed"
    return dict(DEFAULT_IMU)


# --------------------------------------------------------------------------------------------
# Names


_SLUG = re.compile(r"[^a-z0-9]+")
_GENERIC = re.compile(r"_(base_link|link|frame|optical|base)$")
_RESERVED = ("imu", "wheel", "vehicle", "nonholonomic", "steering")


def frame_name(frame: str, kind: str) -> str:
    """A sensor name from a frame: ``velodyne_top_base_link`` → ``velodyne_top``,
    ``camera0/camera_link`` → ``camera0``, ``tamagawa/imu_link`` → ``tamagawa``."""
    parts = [p for p in (_SLUG.sub("_", s.lower()).strip("_") for s in frame.split("/")) if p]
    stripped = []
    for part in parts:
        while True:
            shorter = _GENERIC.sub("", part)
            if shorter == part or not shorter:
                break
            part = shorter
        stripped.append(part)
    # a generic last part (camera_link → camera) names the kind, not the sensor: take its parent
    while len(stripped) > 1 and stripped[-1] in (kind, "camera", "lidar", "imu", "gnss", "gps", "sensor", "link"):
        stripped.pop()
    name = "_".join(stripped[-1:]) or kind
    if not name[0].isalpha():
        name = f"{kind}_{name}"
    if name in _RESERVED:
        name = f"{name}_{kind}"
    return name


def unique(name: str, taken: set[str]) -> str:
    out, k = name, 2
    while out in taken:
        out, k = f"{name}_{k}", k + 1
    taken.add(out)
    return out


def rig_name(path: Path, strip: tuple[str, ...] = ()) -> str:
    """The rig named after its file (the tool's fixed prefixes stripped)."""
    stem = path.name
    for suffix in (".yaml", ".yml", ".urdf", ".xml"):
        stem = stem.removesuffix(suffix)
    for prefix in strip:
        stem = stem.removeprefix(prefix)
    name = _SLUG.sub("_", stem.lower()).strip("_")
    return name or "rig"


# --------------------------------------------------------------------------------------------
# Files


def vector(value: Any, path: Path, key: str, n: int = 3) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        got = f"{len(value)} numbers" if isinstance(value, (list, tuple)) else repr(value)
        raise RigError(f"{path}: {key}: expected {n} numbers, got {got}")
    return np.array([number(v, path, f"{key}[{i}]") for i, v in enumerate(value)])


def matrix(value: Any, path: Path, key: str, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A matrix of ``shape`` (nested rows, a flat row-major list, or ``!!opencv-matrix``) and the
    decimals each entry was printed with (-1 where unknown)."""
    rows, cols = shape
    want = f"a {rows}x{cols} matrix"
    if isinstance(value, OpenCVMatrix):
        if value.problem:
            raise RigError(f"{path}: {key}: {value.problem}")
        missing = [k for k in ("rows", "cols", "data") if k not in value]
        if missing:
            raise RigError(f"{path}: {key}: !!opencv-matrix without {', '.join(missing)}")
        r, c, data = value["rows"], value["cols"], value["data"]
        if (r, c) != shape:
            raise RigError(f"{path}: {key}: expected {want}, got rows: {r}, cols: {c}")
        if not isinstance(data, list) or len(data) != rows * cols:
            n = len(data) if isinstance(data, list) else "no list of"
            raise RigError(f"{path}: {key}.data: rows × cols = {rows * cols}, but data holds {n} numbers")
        flat = data
    elif isinstance(value, OpenCVTag):
        raise RigError(f"{path}: {key}: {value.tag} is not a matrix excite reads (!!opencv-matrix is)")
    elif isinstance(value, list) and len(value) == rows and all(isinstance(r, list) for r in value):
        bad = next((i for i, r in enumerate(value) if len(r) != cols), None)
        if bad is not None:
            raise RigError(f"{path}: {key}: expected {want}, row {bad} has {len(value[bad])} numbers")
        flat = [x for r in value for x in r]
    elif isinstance(value, list) and len(value) == rows * cols and not any(isinstance(x, list) for x in value):
        flat = value
    else:
        got = (f"{len(value)} rows" if isinstance(value, list) and value and isinstance(value[0], list)
               else f"{len(value)} numbers" if isinstance(value, list) else repr(value))
        raise RigError(f"{path}: {key}: expected {want} (rows, or {rows * cols} numbers row by row), got {got}")
    M = np.array([number(x, path, key) for x in flat]).reshape(shape)
    dec = np.array([getattr(x, "decimals", -1) if not isinstance(x, int) else 0 for x in flat]).reshape(shape)
    return M, dec


def transform(value: Any, path: Path, key: str, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """A 4×4 homogeneous transform: its rotation (to the precision of its digits) and translation."""
    T, dec = matrix(value, path, key, (4, 4))
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise RigError(f"{path}: {key}: the last row is {T[3].tolist()}, not [0, 0, 0, 1]")
    return rotation(T[:3, :3], dec[:3, :3], path, key, notes), T[:3, 3]


def rotation_tolerance(M: np.ndarray, decimals: np.ndarray) -> tuple[float, str]:
    """The Frobenius distance from a rotation that rounding to the printed digits can make, and
    how the digits were counted."""
    d = np.where(decimals < 0, 17, decimals)  # unknown: a double's full precision
    trivial = np.isin(M, (0.0, 1.0, -1.0))
    if (~trivial).any():
        d = np.where(trivial, d[~trivial].min(), d)
    else:
        d = np.full_like(d, 17)
    tol = float(np.sqrt(np.sum((0.5 * 10.0 ** (-d.astype(float))) ** 2)))
    lo, hi = int(d.min()), int(d.max())
    digits = f"{lo} decimals" if lo == hi else f"{lo}–{hi} decimals"
    return tol + ARITHMETIC_TOL, digits


def rotation(M: np.ndarray, decimals: np.ndarray, path: Path, key: str, notes: list[str]) -> np.ndarray:
    """The rotation a printed 3×3 matrix stands for (see the module notes); a correction beyond
    the arithmetic's is noted."""
    u, _, vt = np.linalg.svd(M)
    if np.linalg.det(u @ vt) < 0:
        raise RigError(f"{path}: {key}: the rotation block has determinant {np.linalg.det(M):.4g}: a reflection, "
                       "not a rotation (one axis is flipped)")
    R = u @ vt
    dev = float(np.linalg.norm(M - R))
    tol, digits = rotation_tolerance(M, decimals)
    if dev > tol:
        raise RigError(f"{path}: {key}: the rotation block is {dev:.2g} from the nearest rotation (Frobenius "
                       f"norm; |RᵀR − I| = {np.abs(M.T @ M - np.eye(3)).max():.2g}), more than its printed "
                       f"digits ({digits}) allow ({tol:.2g}): not a rotation")
    if dev > ARITHMETIC_TOL:
        notes.append(f"{key}: re-orthonormalised, corrected by {dev:.2g} (Frobenius; its {digits} allow {tol:.2g})")
    return R


# --------------------------------------------------------------------------------------------
# The rig YAML


def _flow(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=10_000).strip()
    return text[:-3].rstrip() if text.endswith("\n...") else text  # a scalar's document end


def rig_yaml(rig: ImportedRig) -> str:
    """The rig as YAML: the notes as a header, each key the source could not tell marked
    ``# REVIEW: why``."""
    cfg, review = rig.config, rig.review

    def tag(key: str) -> str:
        return f"   # REVIEW: {review[key]}" if key in review else ""

    def pose_lines(indent: str, p: dict[str, Any]) -> list[str]:
        return [f"{indent}{k}: {_flow(p[k])}" for k in ("translation_m", "matrix") if k in p]

    out = [f"# {n}" for n in rig.notes]
    if review:
        out.append("# Keys marked REVIEW are not in the source files: check them before trusting a score.")
    out.append(f"name: {_flow(cfg['name'])}")
    out.append(f"imu:{tag('imu')}")
    out += [f"  {k}: {_flow(v)}" for k, v in cfg["imu"].items()]
    out += ["vehicle:", f"  T_V_B:{tag('vehicle.T_V_B')}", *pose_lines("    ", cfg["vehicle"]["T_V_B"])]
    out.append("sensors:" if cfg["sensors"] else "sensors: []")
    for i, s in enumerate(cfg["sensors"]):
        key = f"sensors.{i}"
        out += [f"  - name: {s['name']}", f"    kind: {s['kind']}",
                f"    rate_hz: {_flow(s['rate_hz'])}{tag(f'{key}.rate_hz')}"]
        if "monocular" in s:
            out.append(f"    monocular: {_flow(s['monocular'])}{tag(f'{key}.monocular')}")
        out += [f"    T_B_S:{tag(f'{key}.T_B_S')}", *pose_lines("      ", s["T_B_S"]),
                f"    noise: {_flow(s['noise'])}{tag(f'{key}.noise')}"]
    out.append(f"targets:{tag('targets')}")
    out += [f"  {_flow(k)}: {_flow(v)}" for k, v in cfg["targets"].items()]
    return "\n".join(out) + "\n"


def targets_review() -> str:
    return "accuracy targets are not in the file: defaults per kind (change them to what you need)"
