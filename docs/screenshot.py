"""docs/view.png, made from the real viewer: `python docs/screenshot.py` (`make docs` runs it where Chromium is).

A run of the bundled Leica sample (its first pulses, the default method) is
written to a temporary folder, `fwl view` serves it in this process, and
Debian's headless Chromium (driven by Selenium, as the viewer's browser tests
do) opens the page on the pulse the documentation's URL example names and
saves what it shows. Without chromium and chromedriver on PATH it says so and
leaves the picture as it is.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "examples" / "data" / "leica_als" / "leica_a.las"
PULSE = 7858513358976492  # four echoes, three kept: the pulse docs/viewer.md's URL example opens
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--enable-unsafe-swiftshader", "--window-size=1400,900", "--hide-scrollbars"]


def _wait(driver, script: str, timeout: float = 180) -> object:
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = driver.execute_script(f"return {script}")
        if value:
            return value
        time.sleep(0.2)
    raise TimeoutError(f"the page never had {script}")


def shoot(output: Path) -> None:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    sys.path.insert(0, str(ROOT))
    from pipeline.view.server import make_server, serve_in_thread, url_of

    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(SAMPLE), "--output", str(run),
                        "--limit", "90", "--points-per-range", "40", "--formats", "parquet",
                        "--direct_num_workers=1", "--direct_running_mode=in_memory"], check=True, cwd=ROOT)
        server = make_server([run], port=0, runs_dir=Path(tmp) / "runs")
        serve_in_thread(server)
        options = webdriver.ChromeOptions()
        options.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
        for flag in FLAGS + [f"--user-data-dir={Path(tmp) / 'profile'}"]:
            options.add_argument(flag)
        driver = webdriver.Chrome(service=Service(executable_path=shutil.which("chromedriver")), options=options)
        try:
            driver.get(f"{url_of(server)}?run=0/&pulse=leica_a.las:{PULSE}&colour=amplitude&tab=explore")
            _wait(driver, "document.body.dataset.ready === '1'")
            _wait(driver, f"document.getElementById('waveform').dataset.pulse === '{PULSE}'")
            _wait(driver, "(document.getElementById('map').data || []).some(t => t.meta === 'picked')")
            time.sleep(1.5)  # WebGL's last frame
            driver.save_screenshot(str(output))
        finally:
            driver.quit()
            server.shutdown()
            server.server_close()
    print(f"wrote {output}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "view.png")
    args = parser.parse_args()
    if not (shutil.which("chromium") or shutil.which("chromium-browser")) or not shutil.which("chromedriver"):
        print("docs/screenshot.py: no chromium and chromedriver on PATH; docs/view.png left as it is")
        return 0
    shoot(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
