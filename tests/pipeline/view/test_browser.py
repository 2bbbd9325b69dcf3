"""`fwl view` in a real headless Chromium (Debian's, driven by Selenium with its chromedriver)."""

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
# offline and quiet: no update checks, sync, QUIC or first-run pages; software WebGL for the map and 3D view
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", "--enable-unsafe-swiftshader", "--window-size=1400,900"]


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if CHROMIUM is None or CHROMEDRIVER is None:
        pytest.skip("no chromium and chromedriver on PATH: install Debian's (apt-get install -y chromium "
                    "chromium-driver, as .ci/run does) to run the browser test")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS + [f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(120)
    driver.set_script_timeout(120)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def fwl_view(viewed):
    """`fwl view RUN_DIR` itself, on a free port, until the module ends."""
    fwl = Path(sys.executable).with_name("fwl")
    process = subprocess.Popen([str(fwl), "view", str(viewed.run), "--port", "0", "--no-browser"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    line = process.stdout.readline()
    match = re.search(r"http://127\.0\.0\.1:\d+/", line)
    assert match, line + process.stdout.read() if process.poll() is not None else line
    yield match.group(0)
    process.terminate()
    process.wait(20)


def _wait(driver, script, timeout=120):
    """Until the page's JavaScript expression is truthy; its value."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = driver.execute_script(f"return {script}")
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {script}; page says: {driver.find_element('id', 'message').text}")


def test_the_page_shows_the_run_and_a_clicked_pulse(browser, fwl_view, viewed, tmp_path):
    from selenium.webdriver.common.by import By

    browser.get(fwl_view)
    _wait(browser, "document.body.dataset.ready === '1'")
    runs = browser.find_elements(By.CSS_SELECTOR, "#runs li.run")
    assert len(runs) == 1 and "leica_a.las" in runs[0].text
    # the overview drew the run's echoes: kept and spurious apart, the system returns over them
    traces = _wait(browser, "document.getElementById('map').data && document.getElementById('map').data"
                            ".map(t => [t.meta, t.x.length])")
    echoes = viewed.echoes()
    traces = dict(traces)
    assert traces.pop("picked", None) is not None or True  # the shown pulse, once its answer came
    assert traces == {"returns": int(viewed.pulses().n_system_returns.sum()),
                      "kept": int(echoes.kept.sum()), "spurious": int((~echoes.kept).sum())}

    listed = browser.find_elements(By.CSS_SELECTOR, "#pulses li.pulse")
    shown = browser.execute_script("return document.getElementById('waveform').dataset.pulse")
    pick = next(li for li in listed[1:] if li.get_attribute("data-pulse") != shown)
    pulse_id = int(pick.get_attribute("data-pulse"))
    pick.click()
    _wait(browser, f"document.getElementById('waveform').dataset.pulse === '{pulse_id}'")
    components = browser.execute_script(
        "return document.getElementById('waveform').data.filter(t => t.meta === 'component').length")
    rows = browser.find_elements(By.CSS_SELECTOR, "#pulse-echoes tr.echo-row")
    expected = int((echoes.pulse_id == pulse_id).sum())
    assert components == len(rows) == expected > 0
    assert browser.execute_script("return document.getElementById('waveform').data"
                                  ".filter(t => t.meta === 'raw')[0].y.length") == 256
    assert "reproduces the run's echoes" in browser.find_element(By.ID, "pulse-metrics").text
    # the picked pulse is marked on the map, at its echoes
    marked = _wait(browser, "(document.getElementById('map').data.find(t => t.meta === 'picked') || {}).x")
    assert sorted(marked) == pytest.approx(sorted(echoes[echoes.pulse_id == pulse_id].x), abs=1e-6)
    assert f"pulse=leica_a.las%3A{pulse_id}" in browser.current_url  # the state is in the URL
    # nothing came from anywhere but the viewer
    sources = browser.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert sources and all(s.startswith(fwl_view) for s in sources)
    shot = tmp_path / "fwl-view.png"
    browser.save_screenshot(str(shot))
    assert shot.stat().st_size > 20_000
    print(f"screenshot: {shot}")


def test_a_shared_url_opens_the_same_pulse_and_try_compares_fits(browser, fwl_view, viewed, tmp_path):
    from selenium.webdriver.common.by import By

    pulse_id = int(viewed.pulses().sort_values("gps_time").pulse_id.iloc[5])
    echoes = viewed.echoes()
    x0, x1, y0, y1 = echoes.x.min(), echoes.x.median(), echoes.y.min(), echoes.y.max()
    browser.get(f"{fwl_view}?run=0/&pulse=leica_a.las:{pulse_id}&colour=amplitude&tab=try&box={x0},{x1},{y0},{y1}")
    _wait(browser, "document.body.dataset.ready === '1'")
    assert browser.find_element(By.ID, "colour").get_attribute("value") == "amplitude"
    shown = _wait(browser, "document.getElementById('map').data && document.getElementById('map').data"
                           ".filter(t => t.meta === 'kept' || t.meta === 'spurious')"
                           ".reduce((n, t) => n + t.x.length, 0)")
    assert shown == int((echoes.x.between(x0, x1) & echoes.y.between(y0, y1)).sum()) < len(echoes)
    _wait(browser, f"document.getElementById('waveform').dataset.pulse === '{pulse_id}'")
    browser.find_element(By.CSS_SELECTOR, "#try-form select[name=optimizer] option[value=mde]").click()
    browser.find_element(By.CSS_SELECTOR, "#try-form button[type=submit]").click()
    title = _wait(browser, "document.getElementById('try-b-title').textContent.startsWith('yours: mde') && "
                           "document.getElementById('try-b-title').textContent")
    assert "echoes" in title and browser.find_element(By.ID, "try-a-title").text.startswith("the run's: lm")
    assert browser.execute_script("return document.getElementById('try-b').data.length") >= 3
    browser.save_screenshot(str(tmp_path / "fwl-view-try.png"))


def test_clicking_an_echo_on_the_map_or_typing_an_id_shows_its_pulse(browser, fwl_view, viewed):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    browser.get(f"{fwl_view}?run=0/&colour=height&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    echoes = viewed.echoes()
    first_shown = int(viewed.get(f"/api/summary?run={viewed.run_id}")["first_pulse"][1])
    kept = echoes[echoes.kept & (echoes.pulse_id != first_shown)]
    target = kept.iloc[len(kept) // 2]
    # where Plotly drew that echo, in pixels from the map's centre
    dx, dy, first = browser.execute_script("""
        const div = document.getElementById('map'), L = div._fullLayout, r = div.getBoundingClientRect();
        const px = L.xaxis._offset + L.xaxis.l2p(arguments[0]), py = L.yaxis._offset + L.yaxis.l2p(arguments[1]);
        return [px - r.width / 2, py - r.height / 2, div.querySelector('.nsewdrag') !== null];
    """, float(target.x), float(target.y))
    assert first
    before = browser.execute_script("return document.getElementById('waveform').dataset.pulse")
    chain = ActionChains(browser).move_to_element_with_offset(browser.find_element(By.ID, "map"), dx, dy)
    chain.pause(0.5).click().perform()
    clicked = int(_wait(browser, f"document.getElementById('waveform').dataset.pulse !== '{before}' && "
                                 "document.getElementById('waveform').dataset.pulse"))
    near = echoes[(echoes.pulse_id == clicked)]
    assert ((near.x - target.x) ** 2 + (near.y - target.y) ** 2).min() ** 0.5 < 2.0  # an echo under the pointer

    other = int(viewed.pulses().sort_values("gps_time").pulse_id.iloc[-1])
    box = browser.find_element(By.ID, "pulse-id")
    box.clear()
    box.send_keys(str(other))
    browser.find_element(By.CSS_SELECTOR, "#pulse-form button").click()
    _wait(browser, f"document.getElementById('waveform').dataset.pulse === '{other}'")
    assert browser.execute_script("return document.getElementById('waveform').dataset.components") == \
        str(int((echoes.pulse_id == other).sum()))


def test_a_grid_picked_as_a_layer_is_drawn_under_the_echoes(browser, fwl_view, viewed, gridded, tmp_path):
    import rasterio
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import Select

    browser.get(f"{fwl_view}?run=0/&colour=height&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    select = Select(browser.find_element("id", "grid-layer"))
    _wait(browser, "document.getElementById('grid-layer').options.length > 1")
    wanted = next(o.get_attribute("value") for o in select.options if '"highest.tif"' in o.get_attribute("value"))
    select.select_by_value(wanted)
    drawn = _wait(browser, "(document.getElementById('map').data || []).find(t => t.meta === 'grid')")
    with rasterio.open(gridded / "highest.tif") as tif:
        height, width, west, cell = tif.height, tif.width, tif.transform.c, tif.transform.a
        cells = tif.read(1)[::-1]
    assert drawn["type"] == "heatmap" and len(drawn["z"]) == height and {len(r) for r in drawn["z"]} == {width}
    assert drawn["x0"] - drawn["dx"] / 2 == west and drawn["dx"] == cell
    assert [v is None for row in drawn["z"] for v in row] == list(np.isnan(cells).ravel())  # nodata: not drawn
    assert "highest kept echo z" in drawn["colorbar"]["title"]["text"]
    metas = browser.execute_script("return document.getElementById('map').data.map(t => t.meta)")
    assert metas[0] == "grid" and "kept" in metas  # the first trace: under the echoes
    # the layer is in the URL: a reload shows it again
    assert "layer=" in browser.current_url
    browser.get(browser.current_url)
    _wait(browser, "(document.getElementById('map').data || []).find(t => t.meta === 'grid')")
    shot = tmp_path / "fwl-view-grid.png"
    browser.save_screenshot(str(shot))
    print(f"screenshot: {shot}")
    # an echo over the layer is still the one a click picks
    echoes = viewed.echoes()
    shown = browser.execute_script("return document.getElementById('waveform').dataset.pulse")
    kept = echoes[echoes.kept & (echoes.pulse_id.astype(str) != shown)]
    target = kept.iloc[len(kept) // 3]
    dx, dy = browser.execute_script("""
        const div = document.getElementById('map'), L = div._fullLayout, r = div.getBoundingClientRect();
        return [L.xaxis._offset + L.xaxis.l2p(arguments[0]) - r.width / 2, L.yaxis._offset + L.yaxis.l2p(arguments[1])
                - r.height / 2];
    """, float(target.x), float(target.y))
    ActionChains(browser).move_to_element_with_offset(browser.find_element("id", "map"), dx, dy).pause(0.5) \
        .click().perform()
    clicked = int(_wait(browser, f"document.getElementById('waveform').dataset.pulse !== '{shown}' && "
                                 "document.getElementById('waveform').dataset.pulse"))
    near = echoes[echoes.pulse_id == clicked]
    assert ((near.x - target.x) ** 2 + (near.y - target.y) ** 2).min() ** 0.5 < 2.0
    select = Select(browser.find_element("id", "grid-layer"))
    select.select_by_value("")
    _wait(browser, "!document.getElementById('map').data.some(t => t.meta === 'grid')")


def test_a_zoom_into_a_grid_served_in_blocks_draws_its_cells(browser, viewed, gridded, monkeypatch):
    """A grid larger than the page takes comes in blocks; a zoom (here the URL's box) asks for the box's cells."""
    import json
    from urllib.parse import quote

    from pipeline.view import grids
    from pipeline.view.server import make_server, serve_in_thread, url_of

    monkeypatch.setattr(grids, "MAX_CELLS", 30)  # the 14 x 10 cells of the test's grid: blocks of 3 x 3
    server = make_server([viewed.run], port=0, runs_dir=viewed.folder / "runs")
    serve_in_thread(server)
    try:
        echoes = viewed.echoes()
        box = [echoes.x.min(), echoes.x.min() + 9, echoes.y.min(), echoes.y.min() + 7]  # within 6 x 5 cells
        layer = json.dumps(["0/grid", "highest.tif", 1])
        browser.get(f"{url_of(server)}?run=0/&layer={quote(layer)}&box={','.join(f'{v:.2f}' for v in box)}")
        _wait(browser, "document.body.dataset.ready === '1'")
        drawn = _wait(browser, "(document.getElementById('map').data || []).find(t => t.meta === 'grid' && "
                               "t.dx === 2)")
        assert len(drawn["z"]) <= 5 and max(len(r) for r in drawn["z"]) <= 6
        assert drawn["x0"] - 1 <= box[0] < drawn["x0"] + 1 and drawn["y0"] - 1 <= box[2] < drawn["y0"] + 1
        browser.execute_script("Plotly.relayout('map', {'xaxis.autorange': true, 'yaxis.autorange': true})")
        _wait(browser, "document.getElementById('map').data.some(t => t.meta === 'grid' && t.dx === 6)")
    finally:
        server.shutdown()
        server.server_close()


HOSTILE = "<img src=x onerror=document.title='PWNED'>"


def _served(tmp_path_factory, name: str, copies: dict, args: list[str], points_per_range: int):
    """A viewer in this process over a folder holding the given copies, its one input decomposed."""
    from pipeline.view.jobs import Jobs
    from pipeline.view.server import make_server, serve_in_thread, url_of
    from tests.pipeline.view.conftest import Viewed

    folder = tmp_path_factory.mktemp(name)
    for target, data in copies.items():
        (folder / target).write_bytes(data)
    runs = folder / "runs"
    server = make_server([folder], port=0, runs_dir=runs, jobs=Jobs(runs, args, points_per_range))
    serve_in_thread(server)
    (listed,) = Viewed(url_of(server), folder, runs, "", "", []).get("/api/catalog")["inputs"]
    v = Viewed(url_of(server), folder, runs / Path(listed["name"]).stem, "", listed["id"], [])
    listed = v.decompose(listed["id"])
    assert listed["job"]["status"] == "done", (runs / (Path(listed["name"]).stem + ".log")).read_text()
    v.run_id = listed["run"]
    return server, v


@pytest.fixture(scope="module")
def hostile(tmp_path_factory, leica_dir):
    """A flight line whose name is markup, its packet file cut so that rejection reasons repeat the name."""
    from tests.pipeline.view.conftest import POINTS_PER_RANGE, RUN_ARGS

    wdp = (leica_dir / "leica_a.wdp").read_bytes()[: 92 + 256 * 40]
    server, v = _served(tmp_path_factory, "hostile", {f"{HOSTILE}.las": (leica_dir / "leica_a.las").read_bytes(),
                                                      f"{HOSTILE}.wdp": wdp}, RUN_ARGS, POINTS_PER_RANGE)
    yield v
    server.viewer.jobs.stop_all()
    server.shutdown()
    server.server_close()


def test_a_file_named_as_markup_is_shown_as_text(browser, hostile):
    from urllib.parse import quote

    from selenium.webdriver.common.by import By

    summary = hostile.get(f"/api/summary?run={quote(hostile.run_id)}")
    assert summary["rejected"]["total"] > 0 and HOSTILE in summary["rejected"]["rows"][0]["reason"]
    browser.get(f"{hostile.url}?run={quote(hostile.run_id, safe='')}&tab=summary")
    _wait(browser, "document.body.dataset.ready === '1'")
    _wait(browser, "document.querySelectorAll('#rejected-rows tr').length > 1")
    _wait(browser, "document.getElementById('waveform').dataset.pulse")
    for tab in ("explore", "try", "summary"):  # every view drawn, the pulse refitted
        browser.find_element(By.CSS_SELECTOR, f"#tabs button[data-tab={tab}]").click()
        time.sleep(1.0)
    assert browser.title == "fwl view"  # the handler never ran
    assert browser.execute_script("return document.querySelectorAll('img').length") == 0
    assert browser.execute_script("return document.querySelectorAll('[onerror]').length") == 0
    assert f"{HOSTILE}.las" in browser.find_element(By.ID, "runs").text  # shown, as the text it is
    assert f"{HOSTILE}.wdp" in browser.find_element(By.ID, "rejected-rows").text
    assert f"{HOSTILE}.wdp" in browser.find_element(By.ID, "rejected-reasons").text
    assert HOSTILE in browser.find_element(By.ID, "counts").text
    assert f"{HOSTILE}.las" in browser.execute_script("return document.getElementById('pulse-title').textContent")


@pytest.fixture(scope="module")
def riegl(tmp_path_factory):
    from tests.pipeline.view.conftest import run_args

    samples = Path(__file__).resolve().parents[3] / "examples" / "data" / "pulsewaves"
    server, v = _served(tmp_path_factory, "riegl", {f"riegl_example3{s}": (samples / f"riegl_example3{s}").read_bytes()
                                                    for s in (".pls", ".wvs")}, run_args(40), 10)
    yield v
    server.viewer.jobs.stop_all()
    server.shutdown()
    server.server_close()


def test_an_earth_centred_run_is_drawn_in_metres_about_its_centre(browser, riegl):
    """riegl_example3.pls is in EPSG:4978: the map reads east and north in metres from the run's centre, and its
    colour bar spans the 2nd to 98th percentile of what it shows."""
    import numpy as np
    from urllib.parse import quote

    from selenium.webdriver.common.by import By

    browser.get(f"{riegl.url}?run={quote(riegl.run_id, safe='')}&colour=amplitude&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    layout = _wait(browser, "document.getElementById('map')._fullLayout && document.getElementById('map')"
                            "._fullLayout.xaxis.title.text && [document.getElementById('map')._fullLayout.xaxis.title"
                            ".text, document.getElementById('map')._fullLayout.yaxis.title.text, "
                            "document.getElementById('map')._fullLayout.xaxis.range]")
    assert layout[0] == "east (m) from the run's centre" and layout[1] == "north (m) from the run's centre"
    assert all(abs(v) < 5000 for v in layout[2])  # metres about the centre, not 4.1 million of ECEF
    scene = browser.execute_script("return document.getElementById('scene')._fullLayout.scene.zaxis.title.text")
    assert scene == "up (m)"  # the 3D view's short title; the map says where its origin is
    assert browser.find_element(By.ID, "map-origin").text.startswith("origin ") and "EPSG:4978" in \
        browser.find_element(By.ID, "map-origin").text
    kept = browser.execute_script("return document.getElementById('map').data.find(t => t.meta === 'kept').marker")
    served = riegl.get(f"/api/echoes?run={quote(riegl.run_id, safe='')}&colour=amplitude&limit=60000")
    values = np.array([v for v in served["value"] if v is not None])
    lo, hi = np.percentile(values, [2, 98])
    assert kept["cmin"] == pytest.approx(lo, rel=1e-6) and kept["cmax"] == pytest.approx(hi, rel=1e-6)
    assert kept["cmin"] > values.min() and kept["cmax"] < values.max()
    assert "2nd–98th" in kept["colorbar"]["title"]["text"]
    assert max(abs(v) for v in served["x"] + served["y"]) < 5000


def test_an_earth_centred_runs_grid_is_offered_with_why_it_cannot_be_drawn(riegl):
    """The map draws east and north about the run's centre; a grid of its earth-centred x and y cannot lie there."""
    from urllib.parse import quote

    from pipeline.cli import main
    from tests.pipeline.view.test_server import _status

    assert main(["grid", str(riegl.run), "--cell", "5"]) == 0
    (grid,) = riegl.get(f"/api/grids?run={quote(riegl.run_id, safe='')}")["grids"]
    assert "earth-centred" in grid["unavailable"] and grid["layers"]
    status, data = _status(riegl, "GET", f"/api/grid?run={quote(riegl.run_id, safe='')}&grid={quote(grid['id'])}"
                                         f"&map=highest.tif")
    assert status == 400 and b"earth-centred" in data


def _documented_urls() -> list[str]:
    """The viewer URLs the documentation shows (`?run=...`), from every docs page and the README."""
    root = Path(__file__).resolve().parents[3]
    pages = sorted((root / "docs").glob("*.md")) + [root / "README.md"]
    return sorted({m for page in pages for m in re.findall(r"\?run=[^`\s)]+", page.read_text())})


@pytest.mark.parametrize("query", _documented_urls())
def test_a_documented_url_opens_what_it_says(browser, fwl_view, query):
    """Opened on `fwl view` of the Leica sample's run (its first 90 pulses, as the docs' example says)."""
    from urllib.parse import parse_qs

    wanted = {k: v[0] for k, v in parse_qs(query[1:]).items()}
    browser.get(fwl_view + query)
    _wait(browser, "document.body.dataset.ready === '1'")
    if "pulse" in wanted:
        file, pulse = wanted["pulse"].rsplit(":", 1)
        _wait(browser, f"document.getElementById('waveform').dataset.pulse === '{pulse}'")
        assert browser.execute_script("return document.getElementById('waveform').dataset.file") == file
    if "colour" in wanted:
        assert browser.execute_script("return document.getElementById('colour').value") == wanted["colour"]
    if wanted.get("tab") == "try":
        _wait(browser, "document.getElementById('try-b-title').textContent.startsWith('yours')")
    assert browser.execute_script("return document.getElementById('message').textContent") == ""


def test_the_documentation_shows_a_viewer_url():
    assert _documented_urls()


def test_a_viewer_with_a_token_takes_it_once_from_its_url(browser, viewed):
    from pipeline.view.server import make_server, serve_in_thread, url_of

    server = make_server([viewed.run], port=0, runs_dir=viewed.folder / "runs", token="s3cret-token-of-this-test")
    serve_in_thread(server)
    try:
        url = url_of(server)
        assert url.endswith("/?token=s3cret-token-of-this-test")
        browser.get(url)
        _wait(browser, "document.body.dataset.ready === '1'")
        _wait(browser, "document.getElementById('waveform').dataset.pulse")
        assert len(browser.find_elements("css selector", "#runs li.run")) == 1
        assert "token" not in browser.current_url  # kept by the page, not left in the address bar
    finally:
        server.shutdown()
        server.server_close()


# ---------------------------------------------------------------- GEDI: shot numbers beyond 2^53, degrees as metres

def _l1b_samples(shot: int) -> np.ndarray:
    """A shot's received waveform as the L1B granule holds it (rx_sample_start_index counts from 1)."""
    import h5py

    from tests.pipeline.view.conftest import GEDI, GEDI_L1B

    with h5py.File(GEDI / GEDI_L1B) as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            hit = np.flatnonzero(f[beam]["shot_number"][:].astype(np.int64) == shot)
            if hit.size:
                start, count = (int(f[beam][k][hit[0]]) for k in ("rx_sample_start_index", "rx_sample_count"))
                return f[beam]["rxwaveform"][start - 1:start - 1 + count].astype(float)
    raise LookupError(shot)


def _rounded_away(shots) -> list[int]:
    """The shots whose number a JavaScript number (float64) would turn into another."""
    return [s for s in (int(v) for v in shots) if int(float(s)) != s]


def _shown_shot(browser, shot: int) -> None:
    """The page shows THAT shot: its id, and its raw samples equal to the L1B's."""
    _wait(browser, f"document.getElementById('waveform').dataset.pulse === '{shot}'")
    raw = browser.execute_script("return document.getElementById('waveform').data.find(t => t.meta === 'raw').y")
    assert np.array_equal(np.array(raw, dtype=float), _l1b_samples(shot))
    assert browser.execute_script("return document.getElementById('pulse-title').textContent").startswith(
        f"Pulse {shot} of ")
    assert browser.find_element("id", "pulse-id").get_attribute("value") == str(shot)
    assert f"%3A{shot}&" in browser.current_url


def test_a_link_to_a_gedi_shot_and_a_click_in_the_list_show_that_shot(browser, gedi_viewed):
    """Shot numbers beyond 2^53 (19640119700108618 was opened as ...616): a link and a click keep every digit."""
    from urllib.parse import quote

    from selenium.webdriver.common.by import By

    from tests.pipeline.view.conftest import GEDI_L1B

    pulses = gedi_viewed.pulses()
    shots = _rounded_away(pulses.pulse_id)
    assert len(shots) >= 2  # the test's point: ids a float64 rounds to another number
    shot = shots[len(shots) // 2]
    browser.get(f"{gedi_viewed.url}?run={quote(gedi_viewed.run_id, safe='')}&pulse={quote(GEDI_L1B)}:{shot}"
                f"&colour=height&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    _shown_shot(browser, shot)
    assert browser.find_element(By.ID, "message").text == ""
    # the picked shot's echoes, marked on the map, are its rows of the echo table (in the map's metres)
    served = gedi_viewed.get(f"/api/pulse?run={quote(gedi_viewed.run_id, safe='')}&file={GEDI_L1B}&pulse={shot}")
    marked = _wait(browser, "(document.getElementById('map').data.find(t => t.meta === 'picked') || {}).x")
    assert sorted(marked) == pytest.approx(sorted(served["map"]["x"]), abs=1e-6)
    assert served["pulse_id"] == str(shot) and len(served["echo_rows"]) == int((gedi_viewed.echoes().pulse_id
                                                                                == shot).sum())
    # a click on another such shot in the list
    _wait(browser, "document.querySelectorAll('#pulses li.pulse').length > 1")
    listed = browser.find_elements(By.CSS_SELECTOR, "#pulses li.pulse")
    pick = next(li for li in listed if int(li.get_attribute("data-pulse")) in shots
                and int(li.get_attribute("data-pulse")) != shot)
    other = int(pick.get_attribute("data-pulse"))
    assert str(other) in pick.text
    pick.click()
    _shown_shot(browser, other)
    assert "active" in pick.get_attribute("class")
    # a typed id is taken as its digits too
    box = browser.find_element(By.ID, "pulse-id")
    box.clear()
    box.send_keys(f"  {shot}")
    browser.find_element(By.CSS_SELECTOR, "#pulse-form button").click()
    _shown_shot(browser, shot)


def test_a_gedi_run_is_drawn_in_metres_with_distinct_ticks(browser, gedi_viewed, tmp_path):
    """EPSG:4979: the map's ticks were "41, 41, 41" and the 3D view a vertical line (degrees against metres); now
    east and north metres about the run's centre, as far apart as the geodesic says."""
    import pyproj
    from urllib.parse import quote

    browser.get(f"{gedi_viewed.url}?run={quote(gedi_viewed.run_id, safe='')}&colour=height&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    _wait(browser, "document.getElementById('waveform').dataset.pulse")
    for axis in ("xtick", "ytick"):
        labels = browser.execute_script(f"return [...document.querySelectorAll('#map .{axis} text')]"
                                        ".map(t => t.textContent)")
        assert len(labels) >= 3 and len(set(labels)) == len(labels), labels
    titles = browser.execute_script("const L = document.getElementById('map')._fullLayout; "
                                    "return [L.xaxis.title.text, L.yaxis.title.text]")
    assert titles == ["east (m) from the run's centre", "north (m) from the run's centre"]
    origin = browser.find_element("id", "map-origin").text
    assert origin.startswith("origin 13.7") and "°S 44.1" in origin and "EPSG:4979" in origin
    assert browser.execute_script("const S = document.getElementById('scene')._fullLayout.scene; "
                                  "return [S.xaxis.title.text, S.yaxis.title.text, S.zaxis.title.text]") == \
        ["east (m)", "north (m)", "height (m)"]
    echoes = gedi_viewed.echoes()
    geod = pyproj.Geod(ellps="WGS84")
    lat = float(echoes.y.mean())
    east_west = geod.inv(echoes.x.min(), lat, echoes.x.max(), lat)[2]
    north_south = geod.inv(float(echoes.x.mean()), echoes.y.min(), float(echoes.x.mean()), echoes.y.max())[2]
    scene = browser.execute_script("const d = document.getElementById('scene').data.filter(t => t.meta === 'kept' "
                                   "|| t.meta === 'spurious'); return ['x', 'y', 'z'].map(k => d.flatMap(t => t[k]))")
    spans = [max(v) - min(v) for v in scene]
    assert spans[0] == pytest.approx(east_west, rel=0.01) and spans[1] == pytest.approx(north_south, rel=0.01)
    assert spans[2] == pytest.approx(echoes.z.max() - echoes.z.min(), abs=1e-3)  # metres on all three axes
    aspect = browser.execute_script("return document.getElementById('scene')._fullLayout.scene.aspectratio")
    stretch = max(spans[:2]) / 4 / spans[2]  # kilometres wide, 40 m high: heights stretched to a quarter
    assert aspect["z"] == pytest.approx(0.25) and aspect["x"] == pytest.approx(spans[0] / max(spans[:2]))
    assert f"heights ×{stretch:.1f}" in browser.find_element("id", "scene-count").text
    shot = tmp_path / "fwl-view-gedi.png"
    browser.save_screenshot(str(shot))
    print(f"screenshot: {shot}")


def test_a_gedi_shot_shows_its_algorithm_passed_over_modes_and_biomass(browser, gedi_products, tmp_path):
    """The products' columns, where a run's pulses/ has them: the shot's L2A algorithm, its detected modes with the
    ones below the ground passed over (markers on its waveform), its agbd with the error and stratum."""
    from urllib.parse import quote

    from tests.pipeline.view.conftest import GEDI_L1B, PASSED_OVER_DROPS_M

    pulses = gedi_products.pulses()
    row = pulses[pulses.agbd.notna() & pulses.pulse_id.isin(_rounded_away(pulses.pulse_id))].iloc[0]
    shot = int(row.pulse_id)
    browser.get(f"{gedi_products.url}?run={quote(gedi_products.run_id, safe='')}&pulse={quote(GEDI_L1B)}:{shot}")
    _wait(browser, "document.body.dataset.ready === '1'")
    _shown_shot(browser, shot)
    traces = browser.execute_script("return document.getElementById('waveform').data"
                                    ".filter(t => t.meta === 'modes' || t.meta === 'passed-over')"
                                    ".map(t => [t.meta, t.customdata])")
    drawn = {meta: sorted(z) for meta, z in traces}
    ground = float(row.ground_z)
    assert drawn["passed-over"] == pytest.approx(sorted(ground - d for d in PASSED_OVER_DROPS_M), abs=1e-4)
    assert drawn["modes"] == pytest.approx(sorted([ground, ground + float(row.rh[98])]), abs=1e-4)
    text = browser.find_element("id", "pulse-shot").text
    algorithm = 2 if shot % 2 == 0 else 1
    assert f"L2A algorithm a{algorithm}" in text and f"shot number {shot}" in text
    assert f"{row.agbd:.1f} ± {row.agbd_se:.1f} Mg/ha" in text and "GSW_SAm" in text
    assert "4, 2 passed over (below the ground)" in text
    browser.save_screenshot(str(tmp_path / "fwl-view-gedi-products.png"))


def test_a_grid_of_a_gedi_run_lies_under_its_echoes_in_metres(browser, gedi_viewed, tmp_path):
    """fwl grid of a geographic run has cells in degrees: the map draws each scaled to metres about the run's
    centre, under the echoes, its colour bar across the top and the map full height (a grid put first once took
    over the echoes' colour bar and squeezed the map to a strip)."""
    import json
    from urllib.parse import quote

    import pyproj
    import rasterio
    from selenium.webdriver.support.ui import Select

    from pipeline.cli import main

    cell = 0.002
    out = tmp_path / "grid"
    assert main(["grid", str(gedi_viewed.run), "--cell", str(cell), "--output", str(out)]) == 0
    # a grid elsewhere names its run in its mark; the viewer finds grids under its folders: put it beside the run
    target = gedi_viewed.run.parent / "gedi-grid"
    if not target.exists():
        out.rename(target)
    run = quote(gedi_viewed.run_id, safe="")
    (listed,) = gedi_viewed.get(f"/api/grids?run={run}")["grids"]
    assert listed["unavailable"] is None and listed["cell"].startswith("0.002° (216 × 221")
    browser.get(f"{gedi_viewed.url}?run={run}&colour=height&tab=explore")
    _wait(browser, "document.body.dataset.ready === '1'")
    _wait(browser, "document.getElementById('grid-layer').options.length > 1")
    select = Select(browser.find_element("id", "grid-layer"))
    wanted = next(o.get_attribute("value") for o in select.options if '"highest.tif"' in o.get_attribute("value"))
    select.select_by_value(wanted)
    drawn = _wait(browser, "(document.getElementById('map').data || []).find(t => t.meta === 'grid')")
    with rasterio.open(target / "highest.tif") as tif:
        west, north, size = tif.transform.c, tif.transform.f, tif.transform.a
    echoes = gedi_viewed.echoes()
    lon0, lat0 = (echoes.x.min() + echoes.x.max()) / 2, (echoes.y.min() + echoes.y.max()) / 2
    geod = pyproj.Geod(ellps="WGS84")
    east_m = geod.inv(lon0 - size / 2, lat0, lon0 + size / 2, lat0)[2]  # a cell's width at the centre
    assert drawn["dx"] == pytest.approx(east_m, rel=1e-4) and drawn["dx"] != drawn["dy"]
    assert drawn["x0"] - drawn["dx"] / 2 == pytest.approx(np.sign(west - lon0) * geod.inv(lon0, lat0, west, lat0)[2],
                                                          abs=0.5)
    north_m = drawn["y0"] + (len(drawn["z"]) - 0.5) * drawn["dy"]  # the top row's north edge
    assert north_m == pytest.approx(np.sign(north - lat0) * geod.inv(lon0, lat0, lon0, north)[2], abs=0.5)
    box = json.loads(browser.execute_script(
        "const r = document.querySelector('#map .cbgrid').getBoundingClientRect(), "
        "m = document.getElementById('map').getBoundingClientRect(), L = document.getElementById('map')._fullLayout;"
        " return JSON.stringify([r.top - m.top, r.bottom - m.top, L._size.h, m.height])"))
    assert 0 <= box[0] < box[1] <= 70 and box[2] > 0.45 * box[3]  # the bar in the top margin; the map not a strip
    browser.save_screenshot(str(tmp_path / "fwl-view-gedi-grid.png"))
