"""The planners' page (GET /) in a real headless Chromium, against `excite serve` on loopback.

Needs Debian's ``chromium`` and the ``playwright`` Python package (``.ci/run`` installs both;
``playwright install`` is never used). Outside CI the tests skip, naming what is missing; under
CI (``CI=true``) a missing browser fails them. Each test saves a screenshot of its view in a
temporary directory (printed), or in ``$EXCITE_SCREENSHOTS`` when set (how docs/web-*.png are
made).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from excite.core.units import display_unit

from servers import REPO, LiveServer

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
FIGURE_EIGHT = REPO / "trajectories" / "figure_eight.tum"


def _chromium() -> str | None:
    return os.environ.get("EXCITE_CHROMIUM") or shutil.which("chromium") or (
        "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


def _unavailable(reason: str) -> None:
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason} (CI must run the browser tests: .ci/run installs it)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _unavailable("the playwright Python package is not installed (pip install playwright)")
    exe = _chromium()
    if exe is None:
        _unavailable("no chromium executable (apt-get install chromium)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("web"), workers=1, score_workers=1,
                     max_job_time_budget_s=30).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    out = Path(os.environ.get("EXCITE_SCREENSHOTS") or tmp_path_factory.mktemp("screenshots"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"screenshots in {out}")
    return out


def save_shot(page, shots: Path, name: str) -> None:
    """A full-page screenshot. The copies for the README (``$EXCITE_SCREENSHOTS``) are written
    with a 256-colour palette: the README's images are held under 200 KB (test_readme)."""
    png = page.screenshot(full_page=True)
    if os.environ.get("EXCITE_SCREENSHOTS"):
        import io

        from PIL import Image

        im = Image.open(io.BytesIO(png)).convert("RGB")
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            shots / name, optimize=True)
    else:
        (shots / name).write_bytes(png)


class Console:
    """Everything the page wrote to the console as an error, and uncaught exceptions."""

    def __init__(self, page):
        self.errors: list[str] = []
        page.on("console", lambda m: m.type == "error" and self.errors.append(m.text))
        page.on("pageerror", lambda e: self.errors.append(f"uncaught: {e}"))


@pytest.fixture
def page(browser, server):
    ctx = browser.new_context(viewport={"width": 1366, "height": 900})
    pg = ctx.new_page()
    pg.set_default_timeout(60_000)
    pg.console = Console(pg)
    pg.goto(server.url + "/")
    pg.wait_for_selector("#rig-select option[value=robotaxi]", state="attached")
    yield pg
    ctx.close()


def _library_report(segments: int = 0):
    from excite.io import routes
    from excite.score.evaluate import Options, evaluate
    from excite.rig.config import load_rig

    return evaluate(routes.read_tum(FIGURE_EIGHT), load_rig("robotaxi"), Options(segments=segments))


@pytest.mark.browser
@pytest.mark.slow
def test_score_a_route_through_the_file_input(page, shots):
    """Score figure_eight.tum as a planner would: the score and verdict, the σ/target table with
    lidar.trans_z, a segment per reported segment on the map with its information on hover,
    sorting and keyboard zoom; the numbers are the library's on the same file."""
    page.set_input_files("#route-file", str(FIGURE_EIGHT))
    page.fill("#segments", "12")
    page.click("#score-button")
    page.wait_for_selector("#score-value")
    lib = _library_report(segments=12)

    assert float(page.inner_text("#score-value")) == pytest.approx(lib.score, rel=1e-3)
    assert page.inner_text("#summary .badge") == ("PASS" if lib.passed else "FAIL")
    row = page.locator('#params tr[data-name="lidar.trans_z"]')
    assert row.is_visible()
    # σ and target in the command line's units: lidar.trans_z in cm
    lidar_z = next(p for p in lib.parameters if p.name == "lidar.trans_z")
    assert row.locator("td").nth(2).inner_text() == "cm"
    assert float(row.locator("td").nth(0).inner_text()) == pytest.approx(lidar_z.sigma * 100, rel=1e-2)
    assert float(row.locator("td").nth(1).inner_text()) == pytest.approx(lidar_z.target * 100, rel=1e-6)
    assert page.locator("#params tbody tr").count() == len(lib.parameters)

    # sorted by σ/target on a click, descending on a second click
    page.click('#params th button[data-key="ratio"]')
    ratios = {p.name: (np.inf if p.sigma is None else p.sigma / p.target) for p in lib.parameters}
    shown = page.locator("#params tbody tr").evaluate_all("rows => rows.map(r => r.dataset.name)")
    # ascending up to rounding (the service's σ and this process's may differ in the last bits,
    # and wheel.radius_left/right tie to 4 digits)
    assert sorted(shown) == sorted(ratios)
    in_order = [ratios[n] for n in shown]
    assert all(a <= b * (1 + 1e-6) for a, b in zip(in_order, in_order[1:])), list(zip(shown, in_order))
    assert page.get_attribute('#params th:has(button[data-key="ratio"])', "aria-sort") == "ascending"
    page.click('#params th button[data-key="ratio"]')
    assert page.locator("#params tbody tr").first.get_attribute("data-name") == max(ratios, key=ratios.get)

    # the map: one coloured polyline per segment; hovering one shows its own information
    segs = page.locator("#route-map polyline.seg")
    assert segs.count() == len(lib.segments)
    # a point on the stroke of the last segment (drawn on top where the figure eight retraces
    # itself; the bounding box's centre of a curve is off the stroke)
    x, y = segs.last.evaluate("""l => { const p = l.points.getItem(l.points.numberOfItems >> 1);
        const q = new DOMPoint(p.x, p.y).matrixTransform(l.getScreenCTM()); return [q.x, q.y]; }""")
    page.mouse.move(x, y)
    tip = page.locator("#tooltip")
    assert tip.is_visible()
    s = lib.segments[-1]
    assert f"{s.t_start_s:.1f}–{s.t_end_s:.1f} s" in tip.inner_text()
    # weak modes with advice
    assert page.locator("#modes li .advice").count() >= 1
    assert lib.weak_modes[0].advice in page.inner_text("#modes")
    save_shot(page, shots, "web-score.png")

    # keyboard: focus the map, zoom in with +, back with 0
    home = page.get_attribute("#route-map", "viewBox")
    page.focus("#route-map")
    page.keyboard.press("+")
    zoomed = page.get_attribute("#route-map", "viewBox")
    assert float(zoomed.split()[2]) == pytest.approx(float(home.split()[2]) / 1.25)
    page.keyboard.press("0")
    assert page.get_attribute("#route-map", "viewBox") == home
    # leaving the map (pointer away, focus elsewhere) hides the tooltip without a script error
    page.mouse.move(1, 1)
    page.focus("#segments")
    assert not tip.is_visible()
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_drop_a_route_file_on_the_score_form(page):
    """A route file dropped on the form (a real DataTransfer carrying figure_eight.tum's bytes)
    becomes the route: its name shows, the zone lights up while dragged over, and scoring gives
    the library's score on the same file."""
    page.evaluate("""text => {
        const dt = new DataTransfer();
        dt.items.add(new File([text], "figure_eight.tum", {type: "text/plain"}));
        const zone = document.querySelector("#drop");
        zone.dispatchEvent(new DragEvent("dragover", {dataTransfer: dt, bubbles: true, cancelable: true}));
        window.__over = zone.classList.contains("over");
        zone.dispatchEvent(new DragEvent("drop", {dataTransfer: dt, bubbles: true, cancelable: true}));
    }""", FIGURE_EIGHT.read_text())
    assert page.evaluate("() => window.__over") and not page.locator("#drop.over").count()
    assert page.evaluate("() => document.querySelector('#route-file').files[0].name") == "figure_eight.tum"
    page.click("#score-button")
    page.wait_for_selector("#score-value")
    assert float(page.inner_text("#score-value")) == pytest.approx(_library_report().score, rel=1e-3)
    assert page.locator("#summary .warning").count() == 0  # a car's drive
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_motion_no_car_makes_is_warned_about_on_the_page(page, tmp_path):
    rows = [r for r in FIGURE_EIGHT.read_text().splitlines() if not r.startswith("#")]
    f = rows[400].split()
    f[1] = str(float(f[1]) + 500.0)  # one pose 500 m off: a jump
    rows[400] = " ".join(f)
    jump = tmp_path / "jump.tum"
    jump.write_text("\n".join(rows) + "\n")
    page.set_input_files("#route-file", str(jump))
    page.click("#score-button")
    page.wait_for_selector("#summary .warning")
    assert page.inner_text("#summary .warning").startswith("warning: speed ")
    assert "The numbers assume a car." in page.inner_text("#summary")
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_malformed_route_error_shows_next_to_the_field(page, shots, tmp_path):
    """A TUM file with a broken line: the service's problem (field route.text) appears beside
    the route input, which is marked invalid; no report is shown. Likewise a broken rig YAML
    beside the rig field, and a refused duration beside the duration field."""
    bad = tmp_path / "broken.tum"
    lines = FIGURE_EIGHT.read_text().splitlines()
    lines[4] = "0.4 1.0 oops"
    bad.write_text("\n".join(lines) + "\n")
    page.set_input_files("#route-file", str(bad))
    page.click("#score-button")
    err = page.locator("#route-error")
    err.wait_for(state="visible")
    assert re.search(r"line 5", err.inner_text()), err.inner_text()
    assert page.get_attribute("#route-file", "aria-invalid") == "true"
    assert page.locator("#score-result").is_hidden()
    assert page.inner_text("#score-error") == ""

    page.select_option("#rig-select", "@upload")
    rig = tmp_path / "rig.yaml"
    rig.write_text("name: r\nimu: imu.yaml\n")
    page.set_input_files("#rig-file", str(rig))
    page.locator("#rig-error").wait_for(state="visible")
    assert "rig.imu" in page.inner_text("#rig-error")
    save_shot(page, shots, "web-error.png")

    # the plan form: a duration the API refuses, named beside the duration field
    page.select_option("#rig-select", "robotaxi")
    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    page.fill("#plan-duration_s", "0.5")
    page.click("#plan-button")
    page.locator("#plan-duration_s-error").wait_for(state="visible")
    assert "greater than" in page.inner_text("#plan-duration_s-error")  # the API's own words and bound
    assert page.get_attribute("#plan-duration_s", "aria-invalid") == "true"
    assert page.locator("#job").is_hidden()
    # the only console errors are the browser's own notes of the three refused requests
    assert page.console.errors and all("status of 422" in e for e in page.console.errors), page.console.errors


def plan_short(page, time_budget_s: float) -> str:
    """Ask the plan form for a 20 s maneuver in a 60 × 40 m lot; the job's id once it shows."""
    for field, value in {"duration_s": "20", "time_budget_s": f"{time_budget_s:g}", "n_random": "2",
                         "lot_x_m": "60", "lot_y_m": "40", "lon_deg": "11.5", "lat_deg": "48.1"}.items():
        page.fill(f"#plan-{field}", value)
    page.click("#plan-button")
    page.wait_for_selector("#job-id:not(:empty)")
    return page.inner_text("#job-id")


@pytest.mark.browser
@pytest.mark.slow
def test_plan_a_short_maneuver_and_watch_it_finish(page, shots, server):
    """Plan a 20 s maneuver with a 1 s optimizer budget: the job's progress is shown while it
    runs, then the maneuver in the lot, the comparison and working downloads."""
    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    assert page.input_value("#plan-duration_s") == "90"  # the API's default, read from its schema
    job_id = plan_short(page, time_budget_s=1)
    assert page.locator("#job-status").inner_text() in ("queued", "running", "succeeded")
    page.wait_for_selector("#plan-score", timeout=120_000)
    assert page.inner_text("#job-status") == "succeeded"
    assert page.inner_text("#job-iteration") not in ("", "—")

    import httpx

    job = httpx.get(f"{server.url}/v1/jobs/{job_id}").json()
    assert float(page.inner_text("#plan-score")) == pytest.approx(job["result"]["score"], rel=1e-3)
    assert page.locator("#comparison tbody tr").count() == len(job["result"]["comparison"])
    assert page.locator("#lot-map line.seg").count() > 10
    # the lot is drawn from the service's own outline of it: the 60 × 40 m rectangle
    ring = np.array([[float(v) for v in pt.split()] for pt in
                     page.get_attribute("#lot-map path.lot", "d").strip(" Z").lstrip("M").split("L")])
    assert np.ptp(ring[:, 0]) == pytest.approx(60) and np.ptp(ring[:, 1]) == pytest.approx(40)
    hrefs = page.locator("#downloads a").evaluate_all("as => as.map(a => a.getAttribute('href'))")
    assert len(hrefs) == 4
    for href in hrefs:
        r = httpx.get(server.url + href)
        assert r.status_code == 200, (href, r.text)
    tum = np.loadtxt(httpx.get(server.url + hrefs[0]).text.splitlines())
    assert tum.shape[1] == 8 and tum[-1, 0] - tum[0, 0] == pytest.approx(20, abs=0.5)
    # the drawn maneuver stays in the 60 × 40 m lot, as the optimizer promises
    assert np.all(np.abs(tum[:, 1]) <= 30) and np.all(np.abs(tum[:, 2]) <= 20)
    save_shot(page, shots, "web-plan.png")
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_plan_in_a_geojson_lot_with_a_hole_and_a_ramp(page, shots, server, tmp_path):
    """Upload an L-shaped GeoJSON lot (lon/lat) with a building and a ramp: a refused lot is named
    beside the file input, a good one is planned in and drawn (lot, keep-out zone, ramp), and the
    GeoJSON download needs no origin typed in."""
    import json

    import httpx
    from helpers import l_lot

    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    bad = tmp_path / "open.geojson"  # a ring that is not closed: the service names it
    bad.write_text(json.dumps({"type": "Polygon", "coordinates": [[[11.5, 48.1], [11.501, 48.1], [11.501, 48.101]]]}))
    page.set_input_files("#plan-lot-file", str(bad))
    page.click("#plan-button")
    page.locator("#plan-lot-file-error").wait_for(state="visible")
    assert "ring" in page.inner_text("#plan-lot-file-error")
    assert page.get_attribute("#plan-lot-file", "aria-invalid") == "true"
    garbage = tmp_path / "garbage.geojson"  # not JSON at all: the page says so before sending
    garbage.write_text("{not json")
    page.set_input_files("#plan-lot-file", str(garbage))
    page.click("#plan-button")
    page.wait_for_function("() => document.querySelector('#plan-lot-file-error').textContent.includes('not JSON')")

    good = tmp_path / "l_lot.geojson"
    good.write_text(json.dumps(l_lot(ramp=True)))
    page.set_input_files("#plan-lot-file", str(good))
    for field, value in {"duration_s": "20", "time_budget_s": "15", "n_random": "2"}.items():
        page.fill(f"#plan-{field}", value)
    page.select_option("#plan-criterion", "D")
    page.click("#plan-button")
    page.wait_for_selector("#job-id:not(:empty)")
    job_id = page.inner_text("#job-id")
    page.wait_for_selector("#plan-score", timeout=120_000)
    assert page.inner_text("#job-status") == "succeeded"
    job = httpx.get(f"{server.url}/v1/jobs/{job_id}").json()
    assert job["result"]["criterion"] == "D"
    # drawn: the L with its keep-out zone as a second subpath, and the ramp
    d = page.get_attribute("#lot-map path.lot", "d")
    assert d.count("M") == 2 and page.locator("#lot-map path.terrain.ramp").count() == 1
    assert "1 keep-out" in page.inner_text("#lot-legend") and "ramp" in page.inner_text("#lot-legend")
    href = page.locator("#downloads a", has_text="GeoJSON").get_attribute("href")
    assert "lon_deg" not in href
    r = httpx.get(server.url + href)
    assert r.status_code == 200 and r.json()["features"][0]["geometry"]["type"] == "LineString"
    save_shot(page, shots, "web-plan-geojson.png")
    # the only console error is the browser's own note of the one refused request
    assert len(page.console.errors) == 1 and "status of 422" in page.console.errors[0], page.console.errors


@pytest.mark.browser
@pytest.mark.slow
def test_a_car_rig_scores_and_plans_on_the_page(page, shots, server):
    """The bundled sedan (four CAN wheel speeds, the steering angle, a radar) chosen on the page:
    its sensors are listed, the planned car drive scores as the library scores it (the car's own
    parameters in the table, with its σ), and a plan made with it keeps the car's steering-rate
    limit (the rig's 540 deg/s at the wheel, ratio 15, wheelbase 2.70 m: dκ/dt ≤ rate/(ratio·L))."""
    import httpx
    import yaml

    from excite.io import routes
    from excite.rig.config import RIGS_DIR, load_rig
    from excite.score.evaluate import evaluate

    drive = REPO / "examples" / "sedan_planned_60s_control.csv"
    page.select_option("#rig-select", "sedan")
    info = page.inner_text("#rig-info")
    assert "ackermann" in info and "radar_front" in info, info
    page.set_input_files("#route-file", str(drive))
    page.click("#score-button")
    page.wait_for_selector("#score-value, .error:not(:empty)")
    assert page.locator("#score-value").count(), page.locator(".error").all_inner_texts()
    rig = load_rig("sedan")
    lib = evaluate(routes.read_route(drive, suspension=rig.suspension), rig)
    assert float(page.inner_text("#score-value")) == pytest.approx(lib.score, rel=1e-3)
    assert page.locator("#params tbody tr").count() == len(lib.parameters)
    for name in ("wheel.scale_fl", "wheel.wheelbase", "steering.ratio", "steering.offset", "radar_front.rot_z",
                 "wheel.time_offset"):
        row = page.locator(f'#params tr[data-name="{name}"]')
        p = next(p for p in lib.parameters if p.name == name)
        factor, unit = display_unit(p.unit)
        assert float(row.locator("td").nth(0).inner_text()) == pytest.approx(p.sigma * factor, rel=1e-2), name
        assert row.locator("td").nth(2).inner_text() == unit, name
    save_shot(page, shots, "web-score-sedan.png")

    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    job_id = plan_short(page, time_budget_s=2)
    page.wait_for_selector("#plan-score", timeout=180_000)
    assert page.inner_text("#job-status") == "succeeded"
    job = httpx.get(f"{server.url}/v1/jobs/{job_id}").json()
    assert job["result"]["report"]["rig"] == "sedan"
    control = httpx.get(f"{server.url}/v1/jobs/{job_id}/maneuver", params={"format": "control"}).text
    rows = np.array([[float(v) for v in r.split(",")[:3]] for r in control.splitlines()
                     if r and not r.startswith("#") and r[0] not in "t"])
    car = yaml.safe_load((RIGS_DIR / "sedan.yaml").read_text())["ackermann"]
    limit = np.radians(car["steering"]["rate_max_deg_per_s"]) / (car["steering"]["ratio"] * car["wheelbase_m"])
    rate = np.abs(np.diff(rows[:, 2]) / np.diff(rows[:, 0]))
    assert 0.2 * limit < rate.max() <= 1.05 * limit, (rate.max(), limit)
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_cancel_a_running_job(page):
    """A job with a long budget, cancelled from the page once it runs, ends `cancelled`."""
    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    page.fill("#plan-duration_s", "60")
    page.fill("#plan-time_budget_s", "30")
    page.click("#plan-button")
    page.wait_for_function("() => document.querySelector('#job-status').textContent.startsWith('running')")
    page.click("#cancel-button")
    page.wait_for_function("() => document.querySelector('#job-status').textContent === 'cancelled'", timeout=60_000)
    assert page.is_disabled("#cancel-button") and page.is_enabled("#plan-button")
    assert page.console.errors == []


# --------------------------------------------------------------------------------------------
# What the page needs from the API (no browser)


def _live(page, speed: str) -> None:
    """Replay the chosen file in the Live view and wait for the service's final update."""
    page.click("#tab-live")
    page.select_option("#live-speed", speed)
    page.click("#live-start")
    page.wait_for_selector("#live-result[data-phase=final]", timeout=120_000)


@pytest.mark.browser
@pytest.mark.slow
def test_live_view_replays_a_drive_to_the_websocket(page, shots):
    """Live: figure_eight.tum streamed at 10× to /v1/live. Progress bars appear while it streams
    (one row per scored parameter, updates arriving before the end), and the final state is
    `excite score` of the same file: every bar at target/σ capped at 1, the score, no done banner
    (the drive fails robotaxi's targets), and the weakest direction's advice shown."""
    page.set_input_files("#live-file", str(FIGURE_EIGHT))
    page.click("#tab-live")
    page.select_option("#live-speed", "10")  # 9 s of streaming: the first update comes ~1 s in
    page.click("#live-start")
    page.wait_for_function("() => Number(document.querySelector('#live-result').dataset.updates) >= 1", timeout=60_000)
    # an update before the final one (under load the service may still be catching up after the last pose)
    assert page.locator("#live-result").get_attribute("data-phase") in ("streaming", "ending")
    early = page.locator("#live-params tbody progress").evaluate_all("bs => bs.map(b => b.value)")
    assert len(early) > 0 and any(0 < v < 1 for v in early)
    page.wait_for_selector("#live-result[data-phase=final]", timeout=120_000)
    lib = _library_report()

    rows = page.locator("#live-params tbody tr")
    assert rows.count() == len(lib.parameters)
    shown = dict(rows.evaluate_all("rs => rs.map(r => [r.dataset.name, r.querySelector('progress').value])"))
    expected = {p.name: (0.0 if p.sigma is None else min(1.0, p.target / p.sigma)) for p in lib.parameters}
    assert shown.keys() == expected.keys()
    for name, value in expected.items():
        assert shown[name] == pytest.approx(value, rel=1e-6, abs=1e-12), name
    n_ok = sum(p.ok for p in lib.parameters)
    status = page.inner_text("#live-status")
    assert f"{n_ok} of {len(lib.parameters)} parameters within target" in status
    assert float(re.search(r"score (\S+)", status).group(1)) == pytest.approx(lib.score, rel=5e-3), status
    assert not lib.passed and page.locator("#live-done").is_hidden()
    assert "not yet" in status
    # the weakest direction and a short parameter's advice are in the driver's words
    assert page.inner_text("#live-weakest").startswith("Weakest direction")
    worst = max(lib.parameters, key=lambda p: p.sigma / p.target)
    assert page.inner_text(f'#live-params tr[data-name="{worst.name}"] td.needs').startswith("Needs")
    assert int(page.locator("#live-result").get_attribute("data-updates")) >= 5
    assert page.is_enabled("#live-start") and page.is_disabled("#live-stop")
    save_shot(page, shots, "web-live.png")
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_live_view_done_banner_stop_and_errors(page, tmp_path):
    """With targets loose enough for figure_eight.tum (an uploaded rig YAML) the service's done
    event shows the banner and the final says done; Stop closes the stream mid-drive; a TUM line
    that is not 8 numbers is refused in the browser, and a quaternion of norm 2 by the service,
    each under the file field."""
    import yaml

    from excite.io import routes
    from excite.score.evaluate import evaluate
    from excite.rig.config import RIGS_DIR, load_rig

    data = yaml.safe_load((RIGS_DIR / "robotaxi.yaml").read_text())
    data["targets"] = {"*.rot_*": "1 deg", "*.trans_*": "300 cm", "*.time_offset": "20 ms",
                       "imu.gyro_bias_*": "0.1 deg/s", "imu.accel_bias_*": "0.1 m/s^2",
                       "wheel.radius_*": "10 mm", "wheel.track": "50 mm"}
    loose = tmp_path / "loose.yaml"
    loose.write_text(yaml.safe_dump(data))
    assert evaluate(routes.read_tum(FIGURE_EIGHT), load_rig(loose)).passed  # independent: the library
    page.select_option("#rig-select", "@upload")
    page.set_input_files("#rig-file", str(loose))
    page.wait_for_selector("#rig-info:has-text('parameters')")
    page.set_input_files("#live-file", str(FIGURE_EIGHT))
    _live(page, "200")
    banner = page.locator("#live-done")
    assert banner.is_visible() and banner.inner_text().startswith("Done at t = ")
    t_done = float(re.search(r"t = ([\d.]+) s", banner.inner_text()).group(1))
    assert 0 < t_done < 89.9
    assert page.inner_text("#live-status").endswith("· done")
    assert page.locator("#live-params tbody tr.ok").count() == page.locator("#live-params tbody tr").count()

    # Stop mid-drive at real time
    page.select_option("#live-speed", "1")
    page.click("#live-start")
    page.wait_for_selector("#live-result[data-phase=streaming]")
    page.click("#live-stop")
    assert page.locator("#live-result").get_attribute("data-phase") == "stopped"
    assert page.is_enabled("#live-start") and page.is_disabled("#live-stop")
    assert "stopped after" in page.inner_text("#live-status")

    lines = FIGURE_EIGHT.read_text().splitlines()
    broken = tmp_path / "broken.tum"
    broken.write_text("\n".join(lines[:10] + ["1.05 0 0 0 0 0 0"] + lines[10:]) + "\n")
    page.set_input_files("#live-file", str(broken))
    page.click("#live-start")
    # the page reads the file asynchronously (await file.text()) before it shows the error
    page.wait_for_selector("#live-file-error:has-text('line 11')")
    assert "line 11: expected 8 numbers" in page.inner_text("#live-file-error")
    assert page.get_attribute("#live-file", "aria-invalid") == "true"

    bad = [ln.split() for ln in lines[2:]]
    bad[40][4:8] = ["0", "0", "0", "2"]
    broken.write_text("\n".join(" ".join(r) for r in bad) + "\n")
    page.set_input_files("#live-file", str(broken))
    page.select_option("#live-speed", "200")
    page.click("#live-start")
    page.wait_for_selector("#live-result[data-phase=error]")
    assert "quaternion has norm 2" in page.inner_text("#live-file-error")
    assert page.console.errors == []


def test_score_returns_the_route_path_when_asked(server):
    """``track_points``: the drive's path at equally spaced times, in the file's frame: at the
    file's pose times it is where the file says (within the reader's spline fit, a few mm), and
    the polyline is as long as the report's length."""
    import httpx

    text = FIGURE_EIGHT.read_text()
    r = httpx.post(f"{server.url}/v1/score", timeout=120,
                   json={"route": {"format": "tum", "text": text}, "track_points": 2000})
    assert r.status_code == 200, r.text
    body = r.json()
    tr = body["track"]
    assert len(tr["t_s"]) == len(tr["x_m"]) == len(tr["y_m"]) == 2000
    poses = np.loadtxt(text.splitlines())
    assert tr["t_s"][0] == pytest.approx(poses[0, 0]) and tr["t_s"][-1] == pytest.approx(poses[-1, 0])
    for axis, col in (("x_m", 1), ("y_m", 2)):
        at_poses = np.interp(poses[:, 0], tr["t_s"], tr[axis])
        assert np.max(np.abs(at_poses - poses[:, col])) < 0.02, axis
    length = np.hypot(np.diff(tr["x_m"]), np.diff(tr["y_m"])).sum()
    assert length == pytest.approx(body["length_m"], rel=0.01)
    # not asked: no path
    r = httpx.post(f"{server.url}/v1/score", timeout=120, json={"route": {"format": "tum", "text": text}})
    assert r.status_code == 200 and r.json()["track"] is None


def test_parse_rig_yaml(server):
    """The bundled rig's YAML comes back as the same mapping, which scores like the bundled rig;
    broken files are refused with the field named."""
    import httpx
    import yaml

    from excite.rig.config import RIGS_DIR

    text = (RIGS_DIR / "robotaxi.yaml").read_text()
    r = httpx.post(f"{server.url}/v1/rigs/parse", json={"yaml": text})
    assert r.status_code == 200, r.text
    assert r.json()["rig"] == yaml.safe_load(text)
    assert [p["name"] for p in r.json()["summary"]["parameters"]][:1] == ["lidar.rot_x"]
    route = {"control": {"t_s": [0, 10, 20, 30], "speed_mps": [0, 6, 6, 0], "curvature_1pm": [0, 0.1, -0.1, 0]}}
    a = httpx.post(f"{server.url}/v1/score", timeout=120, json={"route": route, "rig": r.json()["rig"]}).json()
    b = httpx.post(f"{server.url}/v1/score", timeout=120, json={"route": route, "rig": "robotaxi"}).json()
    assert a["score"] == pytest.approx(b["score"], rel=1e-12)

    for bad, field, says in [("name: [1,\n", "yaml", "line 2"), ("- a\n- b\n", "yaml", "mapping"),
                             ("a: &x [1]\nb: *x\n", "yaml", "aliases"),
                             ("name: r\nimu: imu.yaml\n", "rig.imu", "inline"),
                             (text + "keyframe_rat_hz: 10\n", "rig.keyframe_rat_hz", "not a key")]:
        r = httpx.post(f"{server.url}/v1/rigs/parse", json={"yaml": bad})
        assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
        (err,) = r.json()["errors"]
        assert err["field"] == field and says in err["message"], (bad, err)
        assert not err["message"].startswith(field.split(".")[-1] + ":"), err  # the key once, in the field


def test_page_and_its_files_are_served(server):
    """GET / is the page; its script and style sheet come from /static, nothing from elsewhere."""
    import httpx

    r = httpx.get(server.url + "/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    refs = re.findall(r'(?:src|href)="([^"]+)"', r.text)
    assert "/static/app.js" in refs and "/static/style.css" in refs
    assert all(u.startswith(("/", "data:", "#")) for u in refs), refs  # offline: no other host
    for u in ("/static/app.js", "/static/style.css"):
        assert httpx.get(server.url + u).status_code == 200


@pytest.mark.browser
@pytest.mark.slow
def test_plan_a_drivable_maneuver_and_see_its_sheet_and_cones(page, shots, server):
    """Tick "drivable": the job plans elements from cones; the page lists the instructions, draws
    the cones in the lot, shows the driver's sheet and offers it (PDF, PNG), the cone layout and
    the plan as downloads."""
    import httpx

    page.click("#tab-plan")
    page.wait_for_selector('[data-limit="speed_max_mps"]', state="attached")
    page.check("#plan-drivable")
    for field, value in {"duration_s": "60", "time_budget_s": "20", "lot_x_m": "80", "lot_y_m": "50"}.items():
        page.fill(f"#plan-{field}", value)
    page.click("#plan-button")
    page.wait_for_selector("#job-id:not(:empty)")
    job_id = page.inner_text("#job-id")
    page.wait_for_selector("#plan-score", timeout=180_000)
    page.wait_for_selector('#sheet[src^="blob:"]', state="attached", timeout=60_000)
    deadline = time.monotonic() + 30
    while page.locator("#sheet").evaluate("img => img.naturalWidth") == 0:  # decoded
        assert time.monotonic() < deadline
        time.sleep(0.2)
    job = httpx.get(f"{server.url}/v1/jobs/{job_id}").json()
    d = job["result"]["drivable"]
    assert page.locator("#instructions li").count() == len(d["instructions"])
    n_cones = len([f for f in d["cones"]["features"] if f["properties"]["role"] == "cone"])
    assert page.locator("#lot-map path.cone").count() == n_cones
    hrefs = page.locator("#downloads a").evaluate_all("as => as.map(a => a.getAttribute('href'))")
    for fmt in ("sheet_pdf", "sheet_png", "cones", "plan"):
        href = next(h for h in hrefs if h.endswith(f"format={fmt}"))
        assert httpx.get(server.url + href).status_code == 200
    save_shot(page, shots, "web-plan-drivable.png")
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_one_click_scores_the_bundled_figure_eight(page, shots):
    """A visitor without a file: one click scores the bundled figure-eight with the chosen rig,
    the same report as the library's on trajectories/figure_eight_control.csv."""
    from excite.io import routes
    from excite.rig.config import load_rig
    from excite.score.evaluate import evaluate

    page.click("#score-reference")
    page.wait_for_selector("#score-value")
    rig = load_rig("robotaxi")
    lib = evaluate(routes.read_route(REPO / "trajectories" / "figure_eight_control.csv", suspension=rig.suspension), rig)
    assert float(page.inner_text("#score-value")) == pytest.approx(lib.score, rel=1e-3)
    assert "figure_eight_control" in page.inner_text("#summary")
    assert page.locator("#params tbody tr").count() == len(lib.parameters)
    assert page.locator("#route-map polyline.seg").count() >= 1
    save_shot(page, shots, "web-reference.png")
    assert page.console.errors == []


@pytest.mark.browser
@pytest.mark.slow
def test_a_bag_scores_through_the_route_input(page, data_dir):
    """An MCAP log goes through the same input: the page asks for its pose topic, posts the bag
    as it is, and shows the library's report of the same bag and topic (no map: a bag's report
    carries no path)."""
    from excite.io.bags import BagSource
    from excite.io.routes import read_route
    from excite.rig.config import load_rig
    from excite.score.evaluate import evaluate

    bag = data_dir / "nav2_turtlebot.mcap"
    page.set_input_files("#route-file", str(bag))
    assert page.is_visible("#topic-field")
    page.click("#score-button")
    assert "name the pose topic" in page.inner_text("#topic-error")
    page.fill("#route-topic", "/odom")
    page.click("#score-button")
    page.wait_for_selector("#score-value")
    rig = load_rig("robotaxi")
    lib = evaluate(read_route(bag, bag=BagSource("/odom")), rig)
    assert float(page.inner_text("#score-value")) == pytest.approx(lib.score, rel=1e-3, abs=1e-12)
    assert page.locator("#params tbody tr").count() == len(lib.parameters)
    assert not page.is_visible("#map-figure")


@pytest.mark.browser
@pytest.mark.slow
def test_the_scene_is_drawn_under_the_route_coloured_by_the_lidar(page, shots, tmp_path):
    """Scored in a bundled scene, the route is drawn over the scene's outlines (its buildings,
    one path each) and coloured scan by scan by the lidar's information along its weakest
    direction, each scan saying in words what the scene leaves weak there (the library's
    reading of the same scan); a scene file uploaded from the page is kept and used, a bad one
    named next to the scene field."""
    import json

    from excite.io.routes import read_tum
    from excite.rig.config import load_rig
    from excite.scene.along import seen
    from excite.scene.files import load_scene
    from excite.scene.outline import outlines
    from excite.scene.survey import along_route

    page.wait_for_selector("#scene-select option[value=street_canyon]", state="attached")
    page.select_option("#scene-select", "street_canyon")
    page.set_input_files("#route-file", str(FIGURE_EIGHT))
    page.click("#score-button")
    page.wait_for_selector("#score-value")
    canyon = load_scene("street_canyon")
    assert f"scene street_canyon (sha256 {canyon.digest[:12]})" in page.inner_text("#summary")
    assert page.input_value("#colour-by") == "@scene"
    buildings = [x for x in outlines(canyon)["surfaces"] if x["kind"] == "building"]
    assert page.locator("#route-map path.scene-building").count() == len(buildings)
    expected = along_route(seen(read_tum(FIGURE_EIGHT), load_rig("robotaxi"), canyon))
    scans = page.locator("#route-map polyline[data-reading]")
    assert scans.count() == len(expected)
    labels = scans.evaluate_all("ls => ls.map(l => l.getAttribute('aria-label'))")
    words = {"degenerate": "no information along", "clear": "every direction determined"}
    for label, r in zip(labels, expected):
        t = float(re.match(r"scan at (\S+) s: ", label).group(1))
        assert t == pytest.approx(r["t_s"], abs=0.051)  # the page rounds to 0.1 s
        assert words.get(r["status"], r["status"]) in label, (label, r)
    scans.nth(len(expected) // 2).focus()
    assert "scan at" in page.inner_text("#tooltip")
    save_shot(page, shots, "web-scene.png")

    # a scene file from the page: two walls along x leave every scan's x translation
    walls = {"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {"kind": "wall", "height": 4.0},
         "geometry": {"type": "LineString", "coordinates": [[-150.0, y], [150.0, y]]}} for y in (-40.0, 40.0)]}
    path = tmp_path / "walls.geojson"
    path.write_text(json.dumps(walls))
    page.select_option("#scene-select", "@upload")
    page.set_input_files("#scene-file", str(path))
    digest = load_scene("walls.geojson", data=path.read_bytes()).digest
    page.wait_for_selector(f"#scene-select option[value='{digest}']", state="attached")
    assert page.input_value("#scene-select") == digest
    page.click("#score-button")
    page.wait_for_selector(f"#summary:has-text('walls.geojson (sha256 {digest[:12]})')")
    labels = page.locator("#route-map polyline[data-reading]").evaluate_all(
        "ls => ls.map(l => l.getAttribute('aria-label'))")
    assert labels and all(label.endswith("no information along x translation") for label in labels)
    assert page.locator("#route-map polyline.seg.none").count() == len(labels)
    assert page.locator("#route-map path.scene-wall").count() == 2

    bad = tmp_path / "bad.geojson"
    bad.write_text(json.dumps({"type": "FeatureCollection", "properties": {"crs": "local"}, "features": [
        {"type": "Feature", "properties": {"kind": "wall", "height": -1.0},
         "geometry": {"type": "LineString", "coordinates": [[0.0, 0.0], [10.0, 0.0]]}}]}))
    page.select_option("#scene-select", "@upload")
    page.set_input_files("#scene-file", str(bad))
    page.wait_for_selector("#scene-error:has-text('height')")
    assert "bad.geojson" in page.inner_text("#scene-error")
    # the only console error is the browser's own note of the refused upload
    assert page.console.errors == ["Failed to load resource: the server responded with a status of 422 "
                                   "(Unprocessable Entity)"]


def test_the_page_shows_the_command_lines_units():
    """The page's table of display units is the command line's (excite.core.units), and the
    bundled drive it scores is trajectories/figure_eight_control.csv."""
    js = (REPO / "api" / "static" / "app.js").read_text()
    table = re.search(r"const DISPLAY_UNITS = \{(.*?)\};", js, re.S).group(1)
    entries = re.findall(r'"([^"]+)": \[([^,\]]+), "([^"]*)"\]', table)
    assert {u for u, _, _ in entries} >= {"rad", "m", "s", "rad/s", "m/s^2"}
    for unit, factor, shown in entries:
        f, name = display_unit(unit)
        assert eval(factor.replace("Math.PI", str(math.pi))) == pytest.approx(f) and shown == name, unit
    static = REPO / "api" / "static" / "figure_eight_control.csv"
    assert static.read_bytes() == (REPO / "trajectories" / "figure_eight_control.csv").read_bytes()
