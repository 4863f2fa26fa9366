"""Readers of meshes and point-cloud maps (see :mod:`excite.scene.files` for what each format
becomes): every header read and checked by excite before the library that reads the body
(``pypcd4``, ``laspy`` with ``lazrs``, ``plyfile``, ``trimesh``, ``rosbags``) allocates what it
declares."""

from __future__ import annotations

import io
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import bounds
from ..errors import SceneError
from . import shapes
from .model import Scene
from .points import check_points, scene_from_points

MAX_CLOUD_BYTES = 2 * 2**30
"""Largest point-cloud file [bytes] (the most points a map holds, with a few fields each)."""
MAX_HEADER_BYTES = 64 * 2**10
"""Longest header of a PCD or PLY file [bytes]."""
LAS_SCALE_RANGE = (1e-9, 1.0)
"""A LAS coordinate's step [m]: from a nanometre to a metre."""
MAX_LAS_OFFSET_M = 1e8
"""Largest |offset| of a LAS file's coordinates [m] (Earth-centred coordinates are below 1e7)."""
MAX_MAP_MESSAGES = 10_000
"""Most ``sensor_msgs/PointCloud2`` messages accumulated into one map."""
POINTCLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"


@dataclass(frozen=True)
class Cloud:
    """A point cloud as read: ``points`` (N × 3, float) and ``normals`` (N × 3, or None where the
    file has none)."""

    points: np.ndarray
    normals: np.ndarray | None = None


MAX_MESH_BYTES = 512 * 2**20
"""Largest mesh file [bytes] (a binary STL of the most triangles a scene holds is 100 MB)."""
GROUND_MARGIN_M = 20.0
"""How far the ground added under a scene reaches beyond everything in it [m]."""


def read_bounded(path: Path, data: bytes | None, limit: int) -> bytes:
    """The file's bytes (or ``data``), refused beyond ``limit`` before they are read."""
    if data is None:
        try:
            size = path.stat().st_size
        except OSError:
            raise SceneError("no such file", source=str(path)) from None
        if size > limit:
            raise SceneError(f"{size:,} bytes: more than the {limit:,} a scene file of this kind may have",
                             source=str(path))
        try:
            return path.read_bytes()
        except OSError as exc:
            raise SceneError(f"cannot read: {exc.strerror}", source=str(path)) from None
    if len(data) > limit:
        raise SceneError(f"{len(data):,} bytes: more than the {limit:,} a scene file of this kind may have",
                         source=str(path))
    return data


def _head(path: Path, data: bytes | None) -> tuple[bytes, int]:
    """The first :data:`MAX_HEADER_BYTES` of the file and its size."""
    if data is not None:
        return data[:MAX_HEADER_BYTES], len(data)
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            return fh.read(MAX_HEADER_BYTES), size
    except OSError as exc:
        raise SceneError("no such file" if isinstance(exc, FileNotFoundError) else f"cannot read: {exc.strerror}",
                         source=str(path)) from None


def read(path: Path, data: bytes | None, suffix: str, *, ground: bool) -> Scene:
    """The scene of a mesh or point-cloud file (by ``suffix``)."""
    source = str(path)
    if suffix in (".obj", ".stl") or (suffix == ".ply" and _ply_header(path, data).faces > 0):
        return _mesh_scene(read_mesh(path, data), source, ground)
    cloud = read_points(path, data)
    return scene_from_points(cloud.points, cloud.normals, source=source)


def read_points(path: str | Path, data: bytes | None = None) -> Cloud:
    """The points (and normals, where the file has them) of a ``.pcd``, ``.ply``, ``.las`` or
    ``.laz`` file, every bound checked before the body is read."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".pcd":
        return read_pcd(path, data)
    if suffix in (".las", ".laz"):
        return read_las(path, data)
    if suffix == ".ply":
        return read_ply_points(path, data)
    raise SceneError(f"cannot read {suffix or 'a file without a suffix'} as a point cloud "
                     "(expected .pcd, .ply, .las or .laz)", source=str(path))


def _normals(columns: dict[str, np.ndarray], names: tuple[str, str, str]) -> np.ndarray | None:
    if all(n in columns for n in names):
        return np.column_stack([np.asarray(columns[n], float) for n in names])
    return None


# --- PCD --------------------------------------------------------------------------------------


def read_pcd(path: Path, data: bytes | None = None) -> Cloud:
    """A PCD file (``ascii``, ``binary`` or ``binary_compressed``) through ``pypcd4``, its header
    checked first: at most :data:`~excite.core.bounds.MAX_SCENE_POINTS` points, WIDTH × HEIGHT
    equal to POINTS, float x/y/z fields, and a body that holds what the header declares. An
    organised cloud (HEIGHT > 1) marks missing returns with NaN: those points are dropped; in an
    unorganised one a NaN point is an error."""
    source = str(path)
    head, size = _head(path, data)
    lines, offset = [], 0
    for raw in head.split(b"\n"):
        offset += len(raw) + 1
        line = raw.decode("ascii", "replace").strip()
        if not line or line.startswith("#"):
            continue
        lines.append(line)
        if line.upper().startswith("DATA"):
            break
    else:
        raise SceneError(f"header: no DATA line in the first {MAX_HEADER_BYTES:,} bytes: not a PCD file", source=source)
    if len(lines) > 10:
        raise SceneError(f"header: {len(lines)} lines before the data, a PCD header has at most 10", source=source)
    from pydantic import ValidationError
    from pypcd4 import pypcd4 as pcd

    try:
        meta = pcd.MetaData.parse_header(lines)
    except (ValidationError, ValueError) as exc:
        first = exc.errors()[0] if isinstance(exc, ValidationError) else None
        what = f"{'.'.join(str(x) for x in first['loc']).upper()}: {first['msg']}" if first else str(exc)
        raise SceneError(f"header: {what}", source=source) from None
    if meta.points > bounds.MAX_SCENE_POINTS:
        raise SceneError(f"POINTS: {meta.points:,} declared, more than the {bounds.MAX_SCENE_POINTS:,} a map may hold",
                         source=source)
    if meta.width * meta.height != meta.points:
        raise SceneError(f"WIDTH × HEIGHT: {meta.width} × {meta.height} is not POINTS {meta.points}", source=source)
    if not (len(meta.fields) == len(meta.size) == len(meta.type) == len(meta.count)):
        raise SceneError("FIELDS, SIZE, TYPE and COUNT: not one entry each per field", source=source)
    for axis in "xyz":
        if axis not in meta.fields:
            raise SceneError(f"FIELDS: no {axis} field (fields: {' '.join(meta.fields)})", source=source)
        k = meta.fields.index(axis)
        if meta.type[k] != "F" or meta.size[k] not in (4, 8) or meta.count[k] != 1:
            raise SceneError(f"FIELDS: {axis} must be one float of 4 or 8 bytes", source=source)
    try:
        itemsize = meta.build_dtype().itemsize
    except KeyError as exc:
        raise SceneError(f"SIZE/TYPE: no such PCD field type {exc.args[0]}", source=source) from None
    need = meta.points * itemsize
    body = size - offset
    encoding = meta.data.value
    if encoding == "binary" and body < need:
        raise SceneError(f"DATA: {meta.points:,} points of {itemsize} bytes need {need:,} bytes, the file holds "
                         f"{max(body, 0):,}", source=source)
    if encoding in ("binary_compressed", "binaryscompressed"):
        if body < 8:
            raise SceneError("DATA: binary_compressed without its sizes", source=source)
        sizes = head[offset:offset + 8] if offset + 8 <= len(head) else _slice(path, data, offset, 8)
        compressed, uncompressed = struct.unpack("<II", sizes)
        if uncompressed != need:
            raise SceneError(f"DATA: the compressed body declares {uncompressed:,} bytes, {meta.points:,} points of "
                             f"{itemsize} bytes are {need:,}", source=source)
        if compressed > body - 8:
            raise SceneError(f"DATA: the compressed body declares {compressed:,} bytes, the file holds {body - 8:,}",
                             source=source)
    if encoding == "ascii" and size > MAX_CLOUD_BYTES:
        raise SceneError(f"{size:,} bytes: more than the {MAX_CLOUD_BYTES:,} a point cloud may have", source=source)
    try:
        if data is None:
            with open(path, "rb") as fh:
                cloud = pcd.PointCloud.from_fileobj(fh)
        else:
            cloud = pcd.PointCloud.from_fileobj(io.BytesIO(data))
    except (ValueError, RuntimeError, struct.error, OSError) as exc:
        raise SceneError(f"DATA: cannot be read ({str(exc).splitlines()[0][:200]})", source=source) from None
    pc = cloud.pc_data
    if pc.shape[0] != meta.points:
        raise SceneError(f"DATA: {pc.shape[0]:,} points, POINTS declares {meta.points:,}", source=source)
    cols = {n: pc[n] for n in pc.dtype.names}
    pts = np.column_stack([np.asarray(cols[a], float) for a in "xyz"])
    nrm = _normals(cols, ("normal_x", "normal_y", "normal_z"))
    if meta.height > 1:
        keep = np.isfinite(pts).all(axis=1)
        pts = pts[keep]
        nrm = None if nrm is None else nrm[keep]
    check_points(pts, source, "points")
    return Cloud(pts, nrm)


def _slice(path: Path, data: bytes | None, offset: int, n: int) -> bytes:
    if data is not None:
        return data[offset:offset + n]
    with open(path, "rb") as fh:
        fh.seek(offset)
        return fh.read(n)


# --- LAS / LAZ --------------------------------------------------------------------------------

_LAS_CHUNK = 2_000_000


def read_las(path: Path, data: bytes | None = None) -> Cloud:
    """A LAS or LAZ file through ``laspy`` (LAZ decompressed by ``lazrs``), its header checked
    first: the point count, the scales (a coordinate's step, :data:`LAS_SCALE_RANGE`), the
    offsets and the extent; then read in chunks."""
    import laspy

    source = str(path)
    try:
        reader = laspy.open(io.BytesIO(data) if data is not None else path)
    except FileNotFoundError:
        raise SceneError("no such file", source=source) from None
    except (laspy.errors.LaspyException, ValueError, OSError, struct.error) as exc:
        raise SceneError(f"header: not a LAS file ({str(exc)[:200]})", source=source) from None
    with reader:
        h = reader.header
        n = int(h.point_count)
        if n > bounds.MAX_SCENE_POINTS:
            raise SceneError(f"header.point_count: {n:,} declared, more than the {bounds.MAX_SCENE_POINTS:,} a map "
                             "may hold", source=source)
        scales, offsets = np.asarray(h.scales, float), np.asarray(h.offsets, float)
        lo_s, hi_s = LAS_SCALE_RANGE
        if not (np.all(np.isfinite(scales)) and np.all((np.abs(scales) >= lo_s) & (np.abs(scales) <= hi_s))):
            raise SceneError(f"header.scales: {scales.tolist()}: a coordinate's step must be between {lo_s:g} m and "
                             f"{hi_s:g} m", source=source)
        if not (np.all(np.isfinite(offsets)) and np.all(np.abs(offsets) <= MAX_LAS_OFFSET_M)):
            raise SceneError(f"header.offsets: {offsets.tolist()}: must be within ±{MAX_LAS_OFFSET_M:g} m",
                             source=source)
        mins, maxs = np.asarray(h.mins, float), np.asarray(h.maxs, float)
        if n and (not np.all(np.isfinite(mins) & np.isfinite(maxs)) or
                  np.max(maxs - mins) > bounds.MAX_SCENE_EXTENT_M):
            raise SceneError(f"header.mins/maxs: {mins.tolist()} … {maxs.tolist()}: an extent beyond the "
                             f"{bounds.MAX_SCENE_EXTENT_M:.0f} m a scene may span", source=source)
        if not h.are_points_compressed:
            size = len(data) if data is not None else path.stat().st_size
            need = int(h.offset_to_point_data) + n * int(h.point_format.size)
            if size < need:
                raise SceneError(f"header.point_count: {n:,} points of {h.point_format.size} bytes need {need:,} bytes, "
                                 f"the file holds {size:,}", source=source)
        pts = np.empty((n, 3))
        at = 0
        try:
            for chunk in reader.chunk_iterator(_LAS_CHUNK):
                k = len(chunk)
                if at + k > n:
                    raise SceneError(f"header.point_count: more points than the {n:,} declared", source=source)
                pts[at:at + k, 0] = chunk.x
                pts[at:at + k, 1] = chunk.y
                pts[at:at + k, 2] = chunk.z
                at += k
        except (laspy.errors.LaspyException, ValueError, OSError, struct.error, RuntimeError) as exc:
            raise SceneError(f"points: cannot be read ({str(exc)[:200]})", source=source) from None
        if at != n:
            raise SceneError(f"header.point_count: {n:,} declared, the file holds {at:,}", source=source)
    check_points(pts, source, "points")
    return Cloud(pts)


# --- PLY --------------------------------------------------------------------------------------

_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


@dataclass(frozen=True)
class PlyHeader:
    format: str
    vertices: int
    faces: int
    vertex_properties: tuple[str, ...]
    vertex_bytes: int | None  # one vertex's bytes in a binary file (None: a list property)
    header_bytes: int


def _ply_header(path: Path, data: bytes | None) -> PlyHeader:
    """A PLY file's header, read by excite before any body is: the vertex and face counts
    bounded, x/y/z present, a binary body as long as its vertices need."""
    source = str(path)
    head, size = _head(path, data)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise SceneError(f"header: not a PLY file (no ply … end_header in the first {MAX_HEADER_BYTES:,} bytes)",
                         source=source)
    nl = head.find(b"\n", end)
    header_bytes = (nl + 1) if nl >= 0 else len(head)
    fmt, element, counts, props = "", None, {}, {}
    for raw in head[:end].decode("ascii", "replace").splitlines():
        words = raw.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            element = words[1]
            if not re.fullmatch(r"\d{1,12}", words[2]):
                raise SceneError(f"element {element}: count {words[2]!r} is not a number", source=source)
            counts[element] = int(words[2])
            props[element] = []
        elif words[0] == "property" and element is not None:
            props[element].append(words[1:])
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise SceneError(f"format: {fmt or 'none'}: expected ascii, binary_little_endian or binary_big_endian",
                         source=source)
    nv, nf = counts.get("vertex", 0), counts.get("face", 0)
    if nv > bounds.MAX_SCENE_POINTS:
        raise SceneError(f"element vertex: {nv:,} declared, more than the {bounds.MAX_SCENE_POINTS:,} a scene may hold",
                         source=source)
    if nf > bounds.MAX_SCENE_TRIANGLES:
        raise SceneError(f"element face: {nf:,} declared, more than the {bounds.MAX_SCENE_TRIANGLES:,} triangles a "
                         "scene may hold", source=source)
    vprops = props.get("vertex", [])
    names = tuple(p[-1] for p in vprops)
    for axis in "xyz":
        if axis not in names:
            raise SceneError(f"element vertex: no property {axis}", source=source)
    vbytes = None
    if all(len(p) == 2 and p[0] in _PLY_SIZES for p in vprops):
        vbytes = sum(_PLY_SIZES[p[0]] for p in vprops)
        if fmt != "ascii" and size - header_bytes < nv * vbytes:
            raise SceneError(f"element vertex: {nv:,} vertices of {vbytes} bytes need {nv * vbytes:,} bytes, the "
                             f"file holds {max(size - header_bytes, 0):,}", source=source)
    return PlyHeader(fmt, nv, nf, names, vbytes, header_bytes)


def read_ply_points(path: Path, data: bytes | None = None) -> Cloud:
    """The vertices of a PLY file (a point cloud: no faces) through ``plyfile``, with their
    normals (``nx ny nz``) where it has them; a vertex that is not finite is an error."""
    from plyfile import PlyData, PlyParseError

    source = str(path)
    h = _ply_header(path, data)
    if h.format == "ascii" and (len(data) if data is not None else path.stat().st_size) > MAX_CLOUD_BYTES:
        raise SceneError(f"more than the {MAX_CLOUD_BYTES:,} bytes a point cloud may have", source=source)
    try:
        if data is None:
            with open(path, "rb") as fh:
                ply = PlyData.read(fh)
        else:
            ply = PlyData.read(io.BytesIO(data))
        v = ply["vertex"].data
    except (PlyParseError, ValueError, KeyError, OSError, EOFError, struct.error) as exc:
        raise SceneError(f"element vertex: cannot be read ({str(exc)[:200]})", source=source) from None
    cols = {n: v[n] for n in v.dtype.names}
    pts = np.column_stack([np.asarray(cols[a], float) for a in "xyz"])
    if not np.isfinite(pts).all():
        k = int(np.argmin(np.isfinite(pts).all(axis=1)))
        raise SceneError(f"element vertex: vertex {k} (x, y, z) is not a finite number", source=source)
    check_points(pts, source, "element vertex")
    return Cloud(pts, _normals(cols, ("nx", "ny", "nz")))


# --- meshes -----------------------------------------------------------------------------------


def _mesh_counts(path: Path, body: bytes, suffix: str) -> None:
    """Vertices and faces a mesh file declares or holds, bounded before ``trimesh`` reads it."""
    source = str(path)
    limit = bounds.MAX_SCENE_TRIANGLES
    if suffix == ".stl":
        ascii_stl = body[:5].lower() == b"solid" and b"facet" in body[:1024]
        if ascii_stl:
            n = body.count(b"facet normal")
        else:
            if len(body) < 84:
                raise SceneError("a binary STL needs its 84-byte header", source=source)
            n = struct.unpack("<I", body[80:84])[0]
            if len(body) != 84 + 50 * n:
                raise SceneError(f"header: {n:,} triangles declared need {84 + 50 * n:,} bytes, the file has "
                                 f"{len(body):,}", source=source)
        if n > limit:
            raise SceneError(f"{n:,} triangles, more than the {limit:,} a scene may hold", source=source)
    elif suffix == ".obj":
        nv = body.count(b"\nv ") + body.startswith(b"v ")
        nf = body.count(b"\nf ") + body.startswith(b"f ")
        if nv > limit or nf > limit:
            raise SceneError(f"{nv:,} vertices and {nf:,} faces, more than the {limit:,} a scene may hold",
                             source=source)


def read_mesh(path: Path, data: bytes | None = None):
    """A mesh (PLY with faces, OBJ, STL) through ``trimesh`` as (vertices, triangles), its size
    bounded first; a vertex that is not finite is an error."""
    import trimesh


    source = str(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        _ply_header(path, data)
    body = read_bounded(path, data, MAX_MESH_BYTES)
    _mesh_counts(path, body, suffix)
    try:
        mesh = trimesh.load_mesh(io.BytesIO(body), file_type=suffix[1:], process=False)
    except Exception as exc:  # trimesh raises whatever its parsers meet: name the file, keep one line
        raise SceneError(f"cannot be read as a mesh ({type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''})",
                         source=source) from None
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), float)
    f = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), np.int64)
    if f.shape[0] == 0:
        raise SceneError("no triangles in the mesh", source=source)
    if f.shape[0] > bounds.MAX_SCENE_TRIANGLES:
        raise SceneError(f"{f.shape[0]:,} triangles, more than the {bounds.MAX_SCENE_TRIANGLES:,} a scene may hold",
                         source=source)
    if not np.isfinite(v).all():
        k = int(np.argmin(np.isfinite(v).all(axis=1)))
        raise SceneError(f"vertex {k}: not a finite number", source=source)
    return v, f


def _mesh_scene(mesh, source: str, ground: bool) -> Scene:
    from .model import Surface

    v, f = mesh
    part = Scene(v, f, np.zeros(f.shape[0], dtype=np.int64), (Surface("mesh", Path(source).name),), source=source)
    if not ground:
        return part
    lo, hi = part.bounds
    floor = shapes.ground(lo[0] - GROUND_MARGIN_M, lo[1] - GROUND_MARGIN_M, hi[0] + GROUND_MARGIN_M,
                          hi[1] + GROUND_MARGIN_M, lo[2])
    return Scene.combine([floor, part], source=source)


# --- sensor_msgs/PointCloud2 in a bag ----------------------------------------------------------

_PC2_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def pointcloud2_points(msg, where: str, source: str) -> Cloud:
    """The points of one ``sensor_msgs/PointCloud2`` message (a deserialized one), its layout
    checked against its data first: x/y/z fields of float type within ``point_step``,
    ``row_step`` ≥ ``width`` × ``point_step``, the data ``row_step`` × ``height`` bytes long.
    Points a non-dense cloud marks with NaN are dropped."""
    fields = {f.name: f for f in msg.fields}
    w, h, step, row = int(msg.width), int(msg.height), int(msg.point_step), int(msg.row_step)
    n = w * h
    if n > bounds.MAX_SCENE_POINTS:
        raise SceneError(f"{where}: width × height {w} × {h}: more than the {bounds.MAX_SCENE_POINTS:,} points a map "
                         "may hold", source=source)
    cols = {}
    for name in ("x", "y", "z", "normal_x", "normal_y", "normal_z"):
        f = fields.get(name)
        if f is None:
            if name in "xyz":
                raise SceneError(f"{where}: fields: no {name} (fields: {' '.join(fields)})", source=source)
            continue
        kind = _PC2_TYPES.get(int(f.datatype))
        if kind is None or kind[0] != "f" or int(f.count) != 1:
            raise SceneError(f"{where}: fields.{name}: datatype {f.datatype} × {f.count}, expected one FLOAT32 or "
                             "FLOAT64", source=source)
        size = int(kind[1])
        if int(f.offset) < 0 or int(f.offset) + size > step:
            raise SceneError(f"{where}: fields.{name}: offset {f.offset} + {size} bytes is beyond point_step {step}",
                             source=source)
        cols[name] = (int(f.offset), (">" if msg.is_bigendian else "<") + kind)
    if row < w * step:
        raise SceneError(f"{where}: row_step {row} is less than width × point_step = {w} × {step}", source=source)
    buf = np.asarray(msg.data, dtype=np.uint8)
    if buf.size != row * h:
        raise SceneError(f"{where}: data holds {buf.size:,} bytes, row_step × height = {row} × {h} = {row * h:,}",
                         source=source)
    rows = buf.reshape(h, row)[:, :w * step].reshape(n, step) if n else np.zeros((0, max(step, 1)), np.uint8)
    out = {name: rows[:, off:off + int(t[2])].copy().view(t).ravel().astype(float) for name, (off, t) in cols.items()}
    pts = np.column_stack([out[a] for a in "xyz"])
    nrm = _normals(out, ("normal_x", "normal_y", "normal_z"))
    keep = np.isfinite(pts).all(axis=1)
    if not keep.all():
        if msg.is_dense:
            raise SceneError(f"{where}: is_dense, yet point {int(np.argmin(keep))} is not finite", source=source)
        pts = pts[keep]
        nrm = None if nrm is None else nrm[keep]
    return Cloud(pts, nrm)


def read_bag_map(path: Path, topic: str) -> Scene:
    """The ``sensor_msgs/PointCloud2`` messages on ``topic`` of a bag (ROS 1, ROS 2, MCAP), all in
    one frame, accumulated as a map (:func:`~excite.scene.points.scene_from_points`)."""
    from ..errors import BagError
    from ..io.bags.stream import count_bound, open_bag, stream_messages, topic_connections

    source = str(path)
    try:
        with open_bag(path) as reader:
            cons = topic_connections(path, reader, topic)
            if any(c.msgtype != POINTCLOUD2_TYPE for c in cons):
                raise SceneError(f"topic {topic}: {cons[0].msgtype}, expected {POINTCLOUD2_TYPE}", source=source)
            count_bound(path, topic, cons, MAX_MAP_MESSAGES, "point clouds in one map")
            clouds, total, frame = [], 0, None
            for k, (_, raw) in enumerate(stream_messages(path, reader, cons, topic)):
                where = f"topic {topic}: message {k}"
                try:
                    msg = reader.deserialize(raw, POINTCLOUD2_TYPE)
                except Exception as exc:  # rosbags' deserializers raise what the bytes lead them to
                    raise SceneError(f"{where}: cannot be decoded ({type(exc).__name__})", source=source) from None
                if frame is None:
                    frame = msg.header.frame_id
                elif msg.header.frame_id != frame:
                    raise SceneError(f"{where}: header.frame_id {msg.header.frame_id!r}, the map's earlier messages are "
                                     f"in {frame!r} (a map is in one frame)", source=source)
                total += int(msg.width) * int(msg.height)
                if total > bounds.MAX_SCENE_POINTS:
                    raise SceneError(f"{where}: more than the {bounds.MAX_SCENE_POINTS:,} points a map may hold in all",
                                     source=source)
                clouds.append(pointcloud2_points(msg, where, source))
    except BagError as exc:
        raise SceneError(str(exc)) from None
    if not clouds:
        raise SceneError(f"topic {topic}: no messages", source=source)
    pts = np.vstack([c.points for c in clouds])
    nrm = np.vstack([c.normals for c in clouds]) if all(c.normals is not None for c in clouds) else None
    return scene_from_points(pts, nrm, source=f"{source}:{topic}")
