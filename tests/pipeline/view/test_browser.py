"""`fwl view` in a real headless Chromium (Debian's, driven by Selenium with its chromedriver)."""

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

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
    assert dict(traces) == {"returns": int(viewed.pulses().n_system_returns.sum()),
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
                           ".filter(t => t.meta !== 'returns').reduce((n, t) => n + t.x.length, 0)")
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
    first_shown = viewed.get(f"/api/summary?run={viewed.run_id}")["first_pulse"][1]
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
