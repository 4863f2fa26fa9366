"""Reading the files a rig comes from, within bounds: a rig's YAML, and calibration files as the
tools write them (YAML with OpenCV's dialect, a Kalibr IMU file), and telling which tool's file a
path holds (:func:`detect`, :func:`hint`).

**Bounds.** At most :data:`MAX_FILE_BYTES` are read. YAML anchors and aliases are refused (a few
nested aliases, a "YAML bomb", expand to gigabytes in whoever walks the result).

**Calibration files** (:func:`load_yaml`): OpenCV's ``%YAML:1.0`` first line (not a YAML 1.1
directive) is read as the comment it is; ``!!opencv-matrix`` mappings (``rows``, ``cols``, ``dt``,
``data``) are kept to be checked where their key is read; floats keep the number of decimals
they were printed with (:class:`Printed`: a rotation is checked to the precision of its digits),
and ``1e-3`` is a float (YAML 1.1 reads it as a string).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import yaml

from ..core import bounds
from ..errors import RigError

KALIBR_IMU_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                   "gyroscope_random_walk", "update_rate")
_IMU = re.compile(r"imu(\d+)")


class SafeLoader(yaml.SafeLoader):
    """PyYAML's safe loader without anchors and aliases: a few nested aliases (a "YAML bomb")
    expand to gigabytes in whatever walks the result, so they are refused where they appear."""

    def compose_node(self, parent, index):  # noqa: ANN001
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, "anchors and aliases (*name) are not accepted: "
                                              "write the values out", mark)
        return super().compose_node(parent, index)


MAX_FILE_BYTES = 8 * 2**20  # a rig or calibration file is kilobytes


class Printed(float):
    """A float read from a file, with the number of decimals it was printed with."""

    decimals: int

    def __new__(cls, value: float, decimals: int) -> "Printed":
        obj = super().__new__(cls, value)
        obj.decimals = decimals
        return obj


def decimals_of(text: str) -> int:
    """Decimals of a printed number: ``0.9995`` → 4, ``1.2e-3`` → 4, ``1`` → 0."""
    t = text.strip().lower().lstrip("+-")
    mantissa, _, exponent = t.partition("e")
    frac = mantissa.partition(".")[2]
    try:
        exp = int(exponent) if exponent else 0
    except ValueError:
        exp = 0
    return max(len(frac) - exp, 0)


class OpenCVMatrix(dict):
    """An ``!!opencv-matrix`` mapping, checked where its key is read (``problem`` if its node was
    not a mapping)."""

    problem: str | None = None


class OpenCVTag:
    """An ``!!opencv-…`` node of another type (``opencv-nd-matrix``, …)."""

    def __init__(self, tag: str):
        self.tag = tag


_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)(?:[eE][-+]?[0-9]+)?$")


class _Loader(SafeLoader):
    """YAML as calibration tools write it: floats with their printed decimals (``1e-3`` too,
    which YAML 1.1 reads as a string), OpenCV's matrix tag; no aliases."""


def _construct_float(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> Any:
    text = node.value
    if text.lower().lstrip("+-") in (".inf", ".nan"):
        return loader.construct_yaml_float(node)
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        return loader.construct_yaml_float(node)
    return Printed(value, decimals_of(text))


def _construct_opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> OpenCVMatrix:
    out = OpenCVMatrix()
    if isinstance(node, yaml.MappingNode):
        out.update(loader.construct_mapping(node, deep=True))
    else:
        out.problem = f"!!opencv-matrix holds a {node.id}, not a mapping of rows, cols, dt, data"
    return out


def _construct_opencv_other(loader: yaml.SafeLoader, suffix: str, node: yaml.Node) -> OpenCVTag:
    return OpenCVTag(f"!!opencv-{suffix}")


_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))
_Loader.add_constructor("tag:yaml.org,2002:float", _construct_float)
_Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", _construct_opencv_matrix)
_Loader.add_multi_constructor("tag:yaml.org,2002:opencv-", _construct_opencv_other)

_OPENCV_HEADER = re.compile(r"^%YAML:\d\.\d")


def read_text(path: Path, what: str = "a calibration file") -> str:
    """The text of ``path``, at most :data:`MAX_FILE_BYTES` (checked before reading)."""
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise RigError(f"{path}: {size:,} bytes, over the limit of {MAX_FILE_BYTES:,} for {what}")
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RigError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise RigError(f"{path}: not a text file ({exc.reason})") from None


def load_yaml(path: str | Path, text: str | None = None) -> Any:
    """A YAML file as the tools write it (see the module notes); every problem a
    :class:`RigError` naming the file and the line."""
    path = Path(path)
    text = read_text(path) if text is None else text
    first, nl, rest = text.partition("\n")
    if _OPENCV_HEADER.match(first):
        text = "#" + first + nl + rest  # OpenCV's header is not YAML 1.1's directive: a comment
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader)
    except RecursionError:
        raise RigError(f"{path}: nested more than {bounds.MAX_NESTING} levels deep") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise RigError(f"{path}{where}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
    if bounds.nesting(data) > bounds.MAX_NESTING:
        raise RigError(f"{path}: nested more than {bounds.MAX_NESTING} levels deep")
    return data


def mapping(data: Any, path: Path, what: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise RigError(f"{path}: expected {what} (a mapping at the top level)")
    return data


def find_key(data: Any, key: str, depth: int = 3) -> tuple[dict[str, Any], str] | None:
    """The mapping that holds ``key`` (breadth first, up to ``depth`` levels) and its dotted path."""
    level = [(data, "")]
    for _ in range(depth + 1):
        nxt = []
        for d, prefix in level:
            if not isinstance(d, dict):
                continue
            if key in d:
                return d, prefix
            nxt += [(v, f"{prefix}{k}.") for k, v in d.items() if isinstance(v, dict)]
        level = nxt
    return None


def number(value: Any, path: Path, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RigError(f"{path}: {key}: expected a finite number, got {value!r}")
    return float(value)


def read_kalibr_imu(path: str | Path, which: str | None = None) -> tuple[dict[str, float], list[str]]:
    """The Kalibr IMU densities and rate of an IMU file (``which``: the entry of an output file,
    default its first, ``imu0``), with notes."""
    path = Path(path)
    data = mapping(load_yaml(path), path, "a Kalibr IMU file")
    notes = []
    entries = sorted((k for k in data if isinstance(k, str) and _IMU.fullmatch(k)), key=lambda k: int(k[3:]))
    if entries and not any(k in data for k in KALIBR_IMU_KEYS):
        key = which or entries[0]
        if key not in entries:
            raise RigError(f"{path}: {key}: not an IMU of the file (IMUs: {', '.join(entries)})")
        if len(entries) > 1:
            notes.append(f"{path.name}: {key} of {', '.join(entries)} (excite scores one IMU, the camchain's body frame)")
        block, prefix = data[key], f"{key}."
        if not isinstance(block, dict):
            raise RigError(f"{path}: {key}: expected a mapping of the IMU's densities")
    elif which is not None:
        raise RigError(f"{path}: {which}: the file is a single IMU's (no imu0:, imu1:, …)")
    else:
        block, prefix = data, ""
    missing = [k for k in KALIBR_IMU_KEYS if k not in block]
    if missing:
        raise RigError(f"{path}: {prefix}{missing[0]}: missing (a Kalibr IMU file has {', '.join(KALIBR_IMU_KEYS)}"
                       f"{', at the top level or under imu0:' if not prefix else ''})")
    imu = {k: number(block[k], path, prefix + k) for k in KALIBR_IMU_KEYS}
    notes.append(f"IMU from {path.name}" + (f" ({prefix[:-1]})" if prefix else ""))
    return imu, notes


def _has(data: Any, key: str, depth: int = 3) -> bool:
    return find_key(data, key, depth) is not None


def detect(path: str | Path, text: str | None = None) -> tuple[str, str] | None:
    """(what the file is, the command that imports it), or None when it is none of the formats;
    ``text``: the file's text, already held (the path then only names it)."""
    path = Path(path)
    if text is None:
        try:
            text = read_text(path)
        except RigError:
            return None
    head = text.lstrip()[:2000]
    if head.startswith("<?xml") or head.startswith("<robot") or "<robot" in head:
        if path.suffix == ".xacro" or "xmlns:xacro" in head:
            return "xacro", f"xacro {path.name} > robot.urdf, then `excite rig from-urdf robot.urdf --imu LINK`"
        return "URDF", f"excite rig from-urdf {path} --imu LINK"
    try:
        data = load_yaml(path, text)
    except RigError:
        return None
    if not isinstance(data, dict) or {"sensors", "targets", "vehicle"} & set(data):
        return None  # not a mapping, or a rig (whose own error is the one to read)
    if any(isinstance(v, dict) and ("T_cam_imu" in v or "T_imu_cam" in v) for v in data.values()):
        return "Kalibr camchain", f"excite rig from-kalibr {path} IMU_YAML"
    if "accelerometer_noise_density" in data or any(
            re.fullmatch(r"imu\d+", str(k)) and isinstance(v, dict) and "accelerometer_noise_density" in v
            for k, v in data.items()):
        return "Kalibr IMU", f"excite rig from-kalibr CAMCHAIN {path}"
    if "body_T_cam0" in data:
        return "VINS-Fusion", f"excite rig from-vins {path}"
    if _has(data, "extrinsicRot"):
        return "LIO-SAM", f"excite rig from-lio-sam {path}"
    if _has(data, "extrinsic_R"):
        return "FAST-LIO" + ("/FAST-LIVO" if _has(data, "Rcl") else ""), f"excite rig from-fast-lio {path}"
    children = [c for v in data.values() if isinstance(v, dict) for c in v.values()]
    if children and all(isinstance(c, dict) and {"x", "y", "z", "roll", "pitch", "yaw"} <= set(c) for c in children):
        frames = [str(f) for v in data.values() if isinstance(v, dict) for f in v]
        if "base_link" in data and not any("imu" in f for f in frames):
            # sensors_calibration.yaml: the kits on base_link; the IMU is in the kit's own file
            return "Autoware calibration", f"excite rig from-autoware SENSOR_KIT_CALIBRATION {path}"
        return "Autoware calibration", f"excite rig from-autoware {path} SENSORS_CALIBRATION"
    return None


def hint(path: str | Path, text: str | None = None) -> str | None:
    """``this is a … file: `excite rig from-… FILE``` for a file of one of the formats."""
    found = detect(path, text)
    if found is None:
        return None
    what, command = found
    also = (f" (or name it as a rig's IMU block: `imu: {Path(path).name}`)" if what == "Kalibr IMU" else "")
    return f"this is {'an' if what[0] in 'AEIO' else 'a'} {what} file, not a rig: `{command}` writes a rig from it{also}"
