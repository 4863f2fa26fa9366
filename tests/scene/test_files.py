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
