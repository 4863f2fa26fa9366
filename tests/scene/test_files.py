"""Scene files read into scenes: what their rays hit is where the file's geometry says (distances
worked out by hand or by pyproj's geodesic, not by the reader), the optimizer's lot features
accepted beside the scene's, the bundled scenes and their known degeneracies, and every hostile
file refused with an error naming the file and the field."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from excite.errors import SceneError
from excite.factors.optics import lidar_beams
from excite.motion.maneuvers import LOT_LENGTH_M, LOT_WIDTH_M
from excite.plan.site import read_site
from excite.scene import lidar
from excite.scene.files import GROUND_MARGIN_M, bundled_scenes, load_scene

BEAMS = lidar_beams(None)


def collection(*features, crs="local"):
    return {"type": "FeatureCollection", "properties": {"crs": crs} if crs else {}, "features": list(features)}


def feature(geometry_type, coordinates, **props):
    return {"type": "Feature", "properties": props, "geometry": {"type": geometry_type, "coordinates": coordinates}}


def rect(x0, y0, x1, y1):
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def write(tmp_path, doc, name="scene.geojson"):
    path = tmp_path / name
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


def ray(scene, origin, direction, reach=500.0):
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    h = scene.cast(np.asarray(origin, float)[None], d[None], reach)
    return (float(h.distance[0]) if h.hit[0] else None), int(h.surface[0])


# --- GeoJSON ---------------------------------------------------------------------------------


def test_a_building_is_hit_where_its_outline_and_height_say(tmp_path):
    path = write(tmp_path, collection(feature("Polygon", rect(10, -5, 20, 5), kind="building", height=8.0,
                                              name="depot")))
    scene = load_scene(path)
    d, s = ray(scene, (0, 0, 2), (1, 0, 0))
    assert d == pytest.approx(10.0, abs=1e-4) and scene.surfaces[s].kind == "building"
    assert scene.surfaces[s].name == "depot"
    d, _ = ray(scene, (15, 0, 30), (0, 0, -1))
    assert d == pytest.approx(30.0 - 8.0, abs=1e-4)  # the roof
    d, s = ray(scene, (0, 0, 9), (1, 0, 0))  # over the roof: nothing
    assert d is None
    d, _ = ray(scene, (0, 0, 2), (1, 1, 0))  # 45°: the corner x = 10 → y = 10 passes the building
    assert d is None
    d, _ = ray(scene, (0, 0, 2), (1, 0.4, 0))  # meets x = 10 at y = 4: inside the wall
    assert d == pytest.approx(10.0 * math.hypot(1, 0.4), abs=1e-4)


def test_a_courtyard_a_wall_and_a_pole(tmp_path):
    courtyard = rect(-30, -30, 30, 30) + [rect(-10, -10, 10, 10)[0][::-1]]
    path = write(tmp_path, collection(
        feature("Polygon", courtyard, height=6.0),
        feature("LineString", [[50, -20], [50, 20], [70, 20]], height=2.0, base=0.5, kind="wall"),
        feature("Point", [100.0, 0.0], radius=0.5, height=4.0),
    ))
    scene = load_scene(path)
    assert ray(scene, (0, 0, 3), (1, 0, 0))[0] == pytest.approx(10.0, abs=1e-4)  # the courtyard's wall
    assert ray(scene, (0, 0, 10), (0, 0, -1))[0] == pytest.approx(10.0, abs=1e-4)  # its open floor: ground
    assert ray(scene, (20, 0, 10), (0, 0, -1))[0] == pytest.approx(4.0, abs=1e-4)  # the roof around it
    assert ray(scene, (40, 0, 1), (1, 0, 0))[0] == pytest.approx(10.0, abs=1e-4)  # the wall's first leg
    assert ray(scene, (40, 10, 0.3), (1, 0, 0))[0] is None  # under the wall's base (a guard rail)
    assert ray(scene, (60, 30, 1), (0, -1, 0))[0] == pytest.approx(10.0, abs=1e-4)  # its second leg
    # the pole: 12 faces, a corner at angle 0; the face between 0° and 30° is r·cos 15° from the centre
    u = np.array([math.cos(math.radians(15)), math.sin(math.radians(15)), 0.0])
    origin = np.array([100.0, 0.0, 2.0]) + 20.0 * u
    d, s = ray(scene, origin, -u)
    assert d == pytest.approx(20.0 - 0.5 * math.cos(math.radians(15)), abs=1e-4)
    assert scene.surfaces[s].kind == "pole"


def test_the_ground_reaches_the_margin_beyond_everything_or_is_the_files(tmp_path):
    doc = collection(feature("Polygon", rect(0, 0, 10, 10), height=5.0),
                     feature("Point", [100.0, 50.0], radius=0.2, height=3.0))
    scene = load_scene(write(tmp_path, doc))
    edge = 100.0 + 0.2 + GROUND_MARGIN_M  # the pole's far side, then the margin
    assert ray(scene, (edge - 0.5, 0, 5), (0, 0, -1))[0] == pytest.approx(5.0, abs=1e-4)
    assert ray(scene, (edge + 0.5, 0, 5), (0, 0, -1))[0] is None
    assert ray(scene, (50, -GROUND_MARGIN_M - 0.5, 5), (0, 0, -1))[0] is None
    assert ray(load_scene(write(tmp_path, doc), ground=False), (50, 5, 5), (0, 0, -1))[0] is None
    doc["features"].append(feature("Polygon", rect(-50, -50, 150, 150), kind="ground", elevation=-1.5))
    scene = load_scene(write(tmp_path, doc))
    d, s = ray(scene, (50, 5, 5), (0, 0, -1))
    assert d == pytest.approx(6.5, abs=1e-4) and scene.surfaces[s].kind == "ground"
    assert ray(scene, (160, 5, 5), (0, 0, -1))[0] is None  # the file's ground only


def test_a_ceiling_faces_down_and_is_hit_from_below(tmp_path):
    scene = load_scene(write(tmp_path, collection(feature("Polygon", rect(-5, -5, 5, 5), kind="ceiling",
                                                          elevation=4.0))))
    d, s = ray(scene, (0, 0, 1), (0, 0, 1))
    assert d == pytest.approx(3.0, abs=1e-4) and scene.surfaces[s].kind == "ceiling"
    tri = scene.triangles[scene.face_surface == s]
    assert np.all(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2] < 0)


def test_the_optimizers_lot_in_the_same_file_is_accepted_and_the_optimizer_reads_the_file(tmp_path):
    doc = collection(
        feature("Polygon", rect(-40, -25, 40, 25) + [rect(-5, -5, 5, 5)[0]], role="lot"),
        feature("Point", [-30.0, 0.0], role="entry", heading_deg=0.0),
        feature("Polygon", rect(10, -10, 20, 0), role="ramp", slope_deg=3.0, uphill_deg=0.0),
        feature("Polygon", rect(-50, 30, -20, 45), kind="building", height=12.0),
    )
    path = write(tmp_path, doc)
    scene = load_scene(path)
    assert set(scene.area_by_kind()) == {"ground", "building"}
    lo, hi = scene.bounds
    assert lo[:2] == pytest.approx([-50 - GROUND_MARGIN_M, -25 - GROUND_MARGIN_M])
    assert hi[:2] == pytest.approx([40 + GROUND_MARGIN_M, 45 + GROUND_MARGIN_M])
    site = read_site(path)  # the buildings are passed over by the optimizer's reader
    assert site.extent_m == (80.0, 50.0) and len(site.lot.holes) == 1 and site.entry is not None


def test_lon_lat_is_projected_about_the_lots_centre(tmp_path):
    """A building 30 m east of the lot's centre in lon/lat: the ray from the centre hits it at the
    geodesic distance pyproj's Geod gives (a transverse Mercator about the centre keeps it)."""
    from pyproj import Geod

    lon0, lat0 = 11.5, 48.1
    dlon = 40.0 / (111_320.0 * math.cos(math.radians(lat0)))
    dlat = 25.0 / 111_132.0
    lot = [[[lon0 - dlon, lat0 - dlat], [lon0 + dlon, lat0 - dlat], [lon0 + dlon, lat0 + dlat],
            [lon0 - dlon, lat0 + dlat], [lon0 - dlon, lat0 - dlat]]]
    face = 0.75 * dlon
    building = [[[lon0 + face, lat0 - dlat / 5], [lon0 + 2 * dlon, lat0 - dlat / 5], [lon0 + 2 * dlon, lat0 + dlat / 5],
                 [lon0 + face, lat0 + dlat / 5], [lon0 + face, lat0 - dlat / 5]]]
    scene = load_scene(write(tmp_path, collection(feature("Polygon", lot, role="lot"),
                                                  feature("Polygon", building, height=10.0), crs=None)))
    _, _, expected = Geod(ellps="WGS84").inv(lon0, lat0, lon0 + face, lat0)
    d, _ = ray(scene, (0, 0, 2), (1, 0, 0))
    assert d == pytest.approx(expected, abs=0.01)


# --- the bundled scenes ----------------------------------------------------------------------


def test_every_bundled_scene_loads_and_the_lots_are_the_projects_lot():
    names = bundled_scenes()
    assert names == sorted(["open_lot", "lot_buildings_one_side", "street_canyon", "tunnel", "highway_guard_rails"])
    from excite.scene.files import BUNDLED

    for name in names:
        scene = load_scene(name)
        assert scene.source == name and scene.n_triangles > 0
        assert (BUNDLED / f"{name}.geojson").stat().st_size < 32_000
        if name in ("open_lot", "lot_buildings_one_side", "street_canyon"):
            assert read_site(BUNDLED / f"{name}.geojson").extent_m == (LOT_LENGTH_M, LOT_WIDTH_M)


def _translation_x_free(H):
    return H[3, 3] == 0.0 and np.all(H[3] == 0.0)


def test_bundled_scenes_leave_free_what_their_geometry_leaves_free():
    """The open lot leaves x, y and yaw free, the tunnel (straight along x, away from its ends) the
    translation along x; the street canyon and the lot with buildings determine all six."""
    at = np.array([[0.0, 0.0, 1.8]])
    eye = np.eye(3)[None]
    H = lidar.informations(load_scene("open_lot"), eye, at, BEAMS).H[0]
    for k in (2, 3, 4):  # yaw, x, y
        assert np.all(np.abs(H[k]) < 1e-9 * np.abs(H).max())
    H = lidar.informations(load_scene("tunnel"), eye, np.array([[700.0, 0.0, 1.8]]), BEAMS).H[0]
    assert np.all(np.abs(H[3]) < 1e-9 * np.abs(H).max())
    assert np.linalg.matrix_rank(H, tol=1e-9 * np.abs(H).max()) == 5
    for name in ("street_canyon", "lot_buildings_one_side"):
        H = lidar.informations(load_scene(name), eye, at, BEAMS).H[0]
        w = np.linalg.eigvalsh(H)
        assert w[0] > 1e-6 * w[-1], name


# --- hostile GeoJSON -------------------------------------------------------------------------


def refused(path, *words, **kw):
    with pytest.raises(SceneError) as err:
        load_scene(path, **kw)
    text = str(err.value)
    assert str(path) in text and "\n" not in text
    for w in words:
        assert w in text, text
    return text


@pytest.mark.slow
def test_a_polygon_of_a_million_vertices_is_refused_by_its_count(tmp_path):
    ring = ",".join(f"[{math.cos(t):.6f},{math.sin(t):.6f}]" for t in np.linspace(0, 2 * math.pi, 1_000_000))
    text = json.dumps(collection(feature("Polygon", "RING", height=5.0))).replace('"RING"', f"[[{ring}]]")
    path = write(tmp_path, text)
    refused(path, "features[0].geometry.coordinates[0]", "1,000,000 vertices")


def test_a_negative_height_and_other_bad_numbers_are_refused_naming_the_field(tmp_path):
    box = rect(0, 0, 10, 10)
    cases = [
        (feature("Polygon", box, height=-3.0), "features[0].properties.height", "-3.0"),
        (feature("Polygon", box, height=0), "features[0].properties.height", "above 0"),
        (feature("Polygon", box, kind="building"), "features[0].properties.height", "required"),
        (feature("Polygon", box, height="tall"), "features[0].properties.height", '"tall"'),
        (feature("Polygon", box, height=5.0, base=1e300), "features[0].properties.base", "at most"),
        (feature("Point", [0, 0], height=5.0), "features[0].properties.radius", "required"),
        (feature("Point", [0, 0], height=5.0, radius=1e9), "features[0].properties.radius", "at most 50"),
        (feature("Polygon", box, height=5.0, kind="spaceship"), "features[0].properties.kind", "spaceship"),
        (feature("LineString", [[0, 0], [1, 1]], height=2.0, kind="ground"), "features[0].properties.kind", "LineString"),
        (feature("Polygon", box, height=5.0, features_per_m2=-1), "features[0].properties.features_per_m2", "-1"),
        (feature("Polygon", [[[0, 0], [1, "a"], [1, 1], [0, 0]]], height=5.0), "features[0].geometry.coordinates[0]",
         "[x, y]"),
        (feature("Polygon", [[[0, 0], [1, 1], [0, 0]]], height=5.0), "features[0].geometry.coordinates[0]", "at least 3"),
        (feature("LineString", [[0, 0]], height=5.0), "features[0].geometry.coordinates", "at least 2"),
        (feature("Polygon", [[[0, 0], [1, 1], [2, 2], [0, 0]]], height=5.0), "encloses no area"),
        (feature("GeometryCollection", [], height=5.0), "features[0].geometry.type"),
        ({"type": "Feature", "properties": {"height": 2.0}, "geometry": "here"}, "features[0].geometry"),
    ]
    for k, (feat, *words) in enumerate(cases):
        refused(write(tmp_path, collection(feat), f"bad{k}.geojson"), *words)


def test_malformed_documents_are_refused(tmp_path):
    refused(write(tmp_path, '{"type": "FeatureCollection", "features": [', "cut.geojson"), "not valid JSON")
    nan = '{"type": "Feature", "properties": {"height": NaN}, "geometry": {"type": "Point", "coordinates": [0, 0]}}'
    refused(write(tmp_path, nan, "nan.geojson"), "NaN")
    refused(write(tmp_path, "[1, 2]", "list.geojson"), "GeoJSON object")
    refused(write(tmp_path, collection(feature("Polygon", rect(0, 0, 10, 10), role="carpark")), "role.geojson"),
            "features[0]", "carpark")
    far = collection(feature("Polygon", rect(0, 0, 30_000, 10), height=3.0))
    refused(write(tmp_path, far, "far.geojson"), "extent")
    lonlat = collection(feature("Polygon", rect(10, 50, 10.001, 50.001), height=3.0), crs=None)
    lonlat["features"].append(feature("Point", [200.0, 95.0], radius=1.0, height=1.0))
    refused(write(tmp_path, lonlat, "lonlat.geojson"), "lon, lat")
    refused(tmp_path / "absent.geojson", "no such file")
    refused("no_such_scene", "bundled")
    refused(write(tmp_path, "x", "scene.xyz"), ".xyz")
    with pytest.raises(SceneError, match="scene.geojson"):
        load_scene("scene.geojson", data=b"\xff\xfe")


# --- point-cloud maps ------------------------------------------------------------------------

TILT = np.array([0.2, -0.3, 0.9])
TILT = TILT / np.linalg.norm(TILT)


def tilted_plane(n=4000, seed=0):
    """Points on the plane n·x = 1 (n = TILT), over a 20 m × 20 m patch about its foot point."""
    rng = np.random.default_rng(seed)
    u = np.cross(TILT, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(TILT, u)
    a, b = rng.uniform(-10, 10, (2, n))
    return TILT + a[:, None] * u + b[:, None] * w


def check_plane_map(scene, source_kind="map", spacing_rays=400):
    """Every splat lies along the plane's normal, and rays from 5 m off the plane, along its
    normal, within 8 m of its middle, meet it 5 m away (a few may pass between splats)."""
    assert scene.surfaces[0].kind == source_kind
    cos = np.abs(scene.face_normals @ TILT)
    assert cos.min() > 1 - 1e-9
    rng = np.random.default_rng(1)
    u = np.cross(TILT, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(TILT, u)
    a, b = rng.uniform(-8, 8, (2, spacing_rays))
    origins = TILT + a[:, None] * u + b[:, None] * w + 5.0 * TILT
    h = scene.cast(origins, np.broadcast_to(-TILT, origins.shape), 50.0)
    assert h.hit.mean() > 0.99
    assert np.allclose(h.distance[h.hit], 5.0, atol=1e-4)


def write_pcd(path, points, encoding="binary", normals=None):
    from pypcd4 import PointCloud

    if normals is None:
        pc = PointCloud.from_xyz_points(points.astype(np.float32))
    else:
        pc = PointCloud.from_xyz_normal_points(np.hstack([points, normals]).astype(np.float32))
    pc.save(path, encoding=encoding)
    return path


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_a_pcd_map_of_a_plane_gives_the_planes_normal_and_range(tmp_path, encoding):
    from pypcd4 import Encoding

    path = write_pcd(tmp_path / "plane.pcd", tilted_plane(), Encoding(encoding))
    scene = load_scene(path)
    assert scene.n_triangles == 2 * 4000
    check_plane_map(scene)


def test_a_las_and_a_laz_map_of_a_plane(tmp_path):
    import laspy

    pts = tilted_plane() + np.array([500_000.0, 5_400_000.0, 300.0])  # UTM-sized coordinates
    for name in ("plane.las", "plane.laz"):
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = [0.0001, 0.0001, 0.0001]
        header.offsets = [500_000.0, 5_400_000.0, 0.0]
        las = laspy.LasData(header)
        las.x, las.y, las.z = pts.T
        las.write(tmp_path / name)
        scene = load_scene(tmp_path / name)
        # quantised to 0.1 mm: the normals within 1e-4 rad, the splats within 0.1 mm of the plane
        assert np.abs(scene.face_normals @ TILT).min() > 1 - 1e-7
        centre = scene.vertices.reshape(-1, 4, 3).mean(axis=1) - np.array([500_000.0, 5_400_000.0, 300.0])
        assert np.abs(centre @ TILT - 1.0).max() < 2e-4


def test_a_ply_cloud_with_normals_keeps_them(tmp_path):
    from plyfile import PlyData, PlyElement

    pts = tilted_plane(2000)
    rng = np.random.default_rng(3)
    normals = np.tile(TILT, (2000, 1)) * rng.choice([-1.0, 1.0], (2000, 1))  # either sign
    v = np.empty(2000, dtype=[(n, "f8") for n in ("x", "y", "z", "nx", "ny", "nz")])
    for k, n in enumerate(("x", "y", "z")):
        v[n] = pts[:, k]
        v["n" + n] = normals[:, k]
    PlyData([PlyElement.describe(v, "vertex")]).write(tmp_path / "plane.ply")
    check_plane_map(load_scene(tmp_path / "plane.ply"))


def test_a_real_scan_in_ply_is_read_point_for_point(data_dir):
    """small_gicp's test scan (``../shared/data/lidar_scan_pair_small_gicp/source.ply``, from
    koide3/small_gicp, MIT licence, written by CloudCompare): the points read equal its binary
    body decoded by numpy after the header, and every splat's normal is a unit vector."""
    from excite.scene.clouds import read_points

    path = data_dir / "lidar_scan_pair_small_gicp" / "source.ply"
    raw = path.read_bytes()
    body = raw[raw.index(b"end_header\n") + len(b"end_header\n"):]
    ref = np.frombuffer(body, dtype="<f4").reshape(-1, 4)[:, :3]
    cloud = read_points(path)
    assert cloud.points.shape == (69792, 3) and cloud.normals is None
    assert np.array_equal(cloud.points, ref.astype(float))
    scene = load_scene(path)
    assert scene.n_triangles == 2 * 69792
    assert np.allclose(np.linalg.norm(scene.face_normals, axis=1), 1.0)


def test_a_map_denser_than_the_splat_bound_is_thinned_to_its_voxels_centroids():
    """The thinned map equals numpy's own grouping of the points by voxel (np.unique over the
    cells at the side the thinning chose), and a grid half that side would hold too many."""
    from excite.scene.points import thin

    rng = np.random.default_rng(0)
    p = rng.uniform(0, 10, (100_000, 3))
    out, _, side = thin(p, None, limit=5_000)
    lo = p.min(axis=0)
    cells, inverse, count = np.unique(np.floor((p - lo) / side).astype(int), axis=0, return_inverse=True,
                                      return_counts=True)
    ref = np.column_stack([np.bincount(inverse.ravel(), weights=p[:, j]) for j in range(3)]) / count[:, None]
    assert out.shape == ref.shape and out.shape[0] <= 5_000
    assert np.allclose(np.sort(out, axis=0), np.sort(ref, axis=0))
    assert len(np.unique(np.floor((p - lo) / (side / 2)).astype(int), axis=0)) > 5_000


def test_closed_form_normals_equal_numpys_eigenvectors():
    from excite.scene.points import smallest_eigenvectors

    rng = np.random.default_rng(2)
    X = rng.normal(size=(5000, 9, 3)) * np.array([1.0, 0.5, 0.01])
    X = X @ np.linalg.qr(rng.normal(size=(5000, 3, 3)))[0]
    X -= X.mean(axis=1, keepdims=True)
    for C in (np.einsum("nki,nkj->nij", X, X), np.einsum("nki,nkj->nij", X[:, :, :], X) + np.eye(3)):
        v = smallest_eigenvectors(C)
        ref = np.linalg.eigh(C)[1][:, :, 0]
        assert np.allclose(np.abs(np.einsum("ij,ij->i", v, ref)), 1.0, atol=1e-9)


# --- meshes ----------------------------------------------------------------------------------

BOX_OBJ = """# a 10 m x 10 m x 8 m building
v 10 -5 0
v 20 -5 0
v 20 5 0
v 10 5 0
v 10 -5 8
v 20 -5 8
v 20 5 8
v 10 5 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
f 5 6 7 8
f 1 4 3 2
"""


def test_a_mesh_box_scans_as_the_same_box_built_from_shapes(tmp_path):
    """An OBJ box (quads, trimesh triangulates them), and the same box written as STL and PLY
    by trimesh: every scan of it holds the information a box built by shapes.box does."""
    import trimesh

    from excite.scene import shapes
    from excite.scene.model import Scene

    (tmp_path / "box.obj").write_text(BOX_OBJ)
    mesh = trimesh.load_mesh(tmp_path / "box.obj", process=False)
    (tmp_path / "box.stl").write_bytes(mesh.export(file_type="stl"))
    (tmp_path / "box.ply").write_bytes(mesh.export(file_type="ply"))
    m = GROUND_MARGIN_M
    reference = Scene.combine([shapes.ground(10 - m, -5 - m, 20 + m, 5 + m), shapes.box(10, -5, 20, 5, 8.0)])
    R = np.stack([np.eye(3), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])])
    p = np.array([[0.0, 1.0, 1.8], [15.0, -12.0, 1.8]])
    H_ref = lidar.informations(reference, R, p, BEAMS).H
    assert np.all(np.linalg.eigvalsh(H_ref)[:, -1] > 0)
    for name in ("box.obj", "box.stl", "box.ply"):
        scene = load_scene(tmp_path / name)
        assert scene.area_by_kind()["mesh"] == pytest.approx(2 * 100 + 4 * 80, rel=1e-12)
        H = lidar.informations(scene, R, p, BEAMS).H
        assert np.allclose(H, H_ref, rtol=1e-6, atol=1e-6 * np.abs(H_ref).max()), name


# --- PointCloud2 in a bag --------------------------------------------------------------------


def pointcloud2(ts, points, frame="map", *, point_step=None, row_step=None, data=None, x_offset=0, dense=True):
    M = ts.types
    fields = [M["sensor_msgs/msg/PointField"](name=n, offset=x_offset + 4 * k, datatype=7, count=1)
              for k, n in enumerate("xyz")]
    step = point_step or 16
    raw = data
    if raw is None:
        body = np.zeros((len(points), step), np.uint8)
        body[:, :12] = np.ascontiguousarray(points, dtype="<f4").view(np.uint8).reshape(len(points), 12)
        raw = body.ravel()
    header = M["std_msgs/msg/Header"](stamp=M["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=frame)
    return M["sensor_msgs/msg/PointCloud2"](header=header, height=1, width=len(points), fields=fields,
                                            is_bigendian=False, point_step=step,
                                            row_step=row_step if row_step is not None else step * len(points),
                                            data=raw, is_dense=dense)


def write_cloud_bag(path, messages, ts):
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/map", "sensor_msgs/msg/PointCloud2", typestore=ts)
        for k, msg in enumerate(messages):
            w.write(c, 1_700_000_000 * 10**9 + k, ts.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    return path


def typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def test_a_pointcloud2_map_in_a_bag_is_a_scene(tmp_path):
    ts = typestore()
    pts = tilted_plane()
    path = write_cloud_bag(tmp_path / "map_bag", [pointcloud2(ts, pts[:2500]), pointcloud2(ts, pts[2500:])], ts)
    scene = load_scene(path, topic="/map")
    assert scene.n_triangles == 2 * 4000 and scene.source.endswith(":/map")
    check_plane_map(scene)
    refused(path, "topic", "sensor_msgs/PointCloud2")  # no topic named
    with pytest.raises(SceneError, match="/nothing"):
        load_scene(path, topic="/nothing")


def test_a_pointcloud2_whose_layout_disagrees_with_its_data_is_refused(tmp_path):
    from excite.scene.clouds import pointcloud2_points

    ts = typestore()
    pts = tilted_plane(100)
    good = pointcloud2(ts, pts)
    assert pointcloud2_points(good, "m", "f").points.shape == (100, 3)
    cases = [
        (pointcloud2(ts, pts, data=np.zeros(1600 - 1, np.uint8)), "data holds 1,599 bytes"),
        (pointcloud2(ts, pts, row_step=800), "row_step 800"),
        (pointcloud2(ts, pts, x_offset=8), "fields.z: offset 16"),
        (pointcloud2(ts, pts, point_step=8, row_step=800, data=np.zeros(800, np.uint8)), "beyond point_step 8"),
    ]
    for k, (msg, words) in enumerate(cases):
        path = write_cloud_bag(tmp_path / f"bad{k}", [msg], ts)
        refused(path, "/map", "message 0", words, topic="/map")
    nan = pts.copy()
    nan[7] = np.nan
    assert pointcloud2_points(pointcloud2(ts, nan, dense=False), "m", "f").points.shape == (99, 3)
    path = write_cloud_bag(tmp_path / "nan", [pointcloud2(ts, nan)], ts)
    refused(path, "is_dense", "point 7", topic="/map")
    path = write_cloud_bag(tmp_path / "frames", [good, pointcloud2(ts, pts, frame="odom")], ts)
    refused(path, "message 1", "frame_id", topic="/map")


# --- hostile point clouds and meshes ---------------------------------------------------------

PCD_HEADER = """# .PCD v0.7
VERSION 0.7
FIELDS x y z
SIZE 4 4 4
TYPE F F F
COUNT 1 1 1
WIDTH {n}
HEIGHT 1
VIEWPOINT 0 0 0 1 0 0 0
POINTS {n}
DATA {data}
"""


def test_a_pcd_declaring_a_billion_points_is_refused_before_anything_is_allocated(tmp_path):
    import tracemalloc

    path = tmp_path / "huge.pcd"
    path.write_bytes(PCD_HEADER.format(n=10**9, data="binary").encode() + b"\0" * 1200)
    tracemalloc.start()
    try:
        refused(path, "POINTS", "1,000,000,000")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 * 2**20
    # within the points bound, but the body too short for what it declares
    path.write_bytes(PCD_HEADER.format(n=1_000_000, data="binary").encode() + b"\0" * 1200)
    refused(path, "DATA", "12,000,000 bytes")
    # a compressed body whose declared size is not that of its points
    path.write_bytes(PCD_HEADER.format(n=100, data="binary_compressed").encode()
                     + np.array([16, 4_000_000_000], "<u4").tobytes() + b"\0" * 16)
    refused(path, "DATA", "4,000,000,000")
    path.write_bytes(PCD_HEADER.format(n=100, data="binary").encode().replace(b"WIDTH 100", b"WIDTH 7")
                     + b"\0" * 1200)
    refused(path, "WIDTH × HEIGHT")
    path.write_bytes(b"\0" * 70_000)
    refused(path, "header", "not a PCD")
    text = PCD_HEADER.format(n=20, data="ascii") + "\n".join(["1 2 3"] * 19 + ["nan 2 3"]) + "\n"
    path.write_text(text)
    refused(path, "point 19", "not a finite number")


def _las_bytes(tmp_path):
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001, 0.001, 0.001]
    las = laspy.LasData(header)
    las.x, las.y, las.z = tilted_plane(500).T
    las.write(tmp_path / "ok.las")
    return bytearray((tmp_path / "ok.las").read_bytes())


def test_a_las_with_an_absurd_scale_or_count_is_refused(tmp_path):
    import struct as st

    base = _las_bytes(tmp_path)
    assert load_scene(tmp_path / "ok.las").n_triangles == 1000
    cases = {
        "scale.las": (131, st.pack("<d", 1e30), ("header.scales", "1e+30")),
        "zero.las": (139, st.pack("<d", 0.0), ("header.scales",)),
        "offset.las": (155, st.pack("<d", float("nan")), ("header.offsets",)),
        "count.las": (107, st.pack("<I", 10**9), ("header.point_count", "1,000,000,000")),
        "short.las": (107, st.pack("<I", 5_000_000), ("header.point_count", "the file holds")),
    }
    for name, (offset, value, words) in cases.items():
        raw = bytearray(base)
        raw[offset:offset + len(value)] = value
        (tmp_path / name).write_bytes(bytes(raw))
        refused(tmp_path / name, *words)


def test_a_ply_with_nan_vertices_or_an_absurd_count_is_refused(tmp_path):
    head = "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    pts = tilted_plane(50).astype("<f4")
    pts[3, 1] = np.nan
    (tmp_path / "nan.ply").write_bytes(head.format(fmt="binary_little_endian", n=50).encode() + pts.tobytes())
    refused(tmp_path / "nan.ply", "element vertex", "vertex 3")
    ascii_body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in pts.astype(float)) + "\n"
    (tmp_path / "nan_ascii.ply").write_text(head.format(fmt="ascii", n=50) + ascii_body)
    refused(tmp_path / "nan_ascii.ply", "vertex 3")
    (tmp_path / "huge.ply").write_bytes(head.format(fmt="binary_little_endian", n=10**9).encode() + b"\0" * 100)
    refused(tmp_path / "huge.ply", "element vertex", "1,000,000,000")
    (tmp_path / "short.ply").write_bytes(head.format(fmt="binary_little_endian", n=5000).encode() + b"\0" * 100)
    refused(tmp_path / "short.ply", "element vertex", "60,000 bytes")
    faces = head.format(fmt="binary_little_endian", n=3).replace(
        "end_header", f"element face {10**9}\nproperty list uchar int vertex_indices\nend_header")
    (tmp_path / "faces.ply").write_bytes(faces.encode() + b"\0" * 100)
    refused(tmp_path / "faces.ply", "element face")


def test_a_mesh_with_a_nan_vertex_or_a_lying_stl_header_is_refused(tmp_path):
    (tmp_path / "nan.obj").write_text(BOX_OBJ.replace("v 20 5 8", "v 20 nan 8"))
    refused(tmp_path / "nan.obj", "vertex 6", "not a finite number")
    body = bytearray(84 + 50 * 2)
    body[80:84] = (10**8).to_bytes(4, "little")
    (tmp_path / "lie.stl").write_bytes(bytes(body))
    refused(tmp_path / "lie.stl", "header", "100,000,000 triangles")
    (tmp_path / "junk.obj").write_text("this is no mesh\n")
    refused(tmp_path / "junk.obj", "mesh")
