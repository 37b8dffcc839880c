"""The served viewer, seen in a real browser: Debian's Chromium, headless, WebGL2 through ANGLE on
SwiftShader, driven over the DevTools protocol (tests/report/cdp.py). The page at the URL `view --serve`
prints must show the recording with pendsim's layout: the measured (blue) and model (orange)
traces drawn in the plots and phase portraits, not Rerun's welcome page. Rerun's web viewer needs
10-20 s to load here; the test takes about 30-40 s."""

import socket
import time

import numpy as np
import pytest
from cdp import Chromium, find_browser
from PIL import Image

from pendsim_bridge.cli import main
from pendsim_bridge.report.rerun_view import SERIES_STYLE
from pendsim_bridge.report.serve import served_viewer

BROWSER = find_browser()
LOAD_TIMEOUT_S = 120.0
MIN_PIXELS = 1500  # each trace colour, in the plots and phase portraits (a loaded view has >10 000)


def _free_port_pair() -> int:
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port + 1))
                return port
            except OSError:
                continue


def colour_pixels(image: np.ndarray, rgb: tuple[int, ...], *, tolerance: int = 40) -> int:
    """How many pixels lie within ``tolerance`` of ``rgb`` in every channel."""
    return int(np.all(np.abs(image[..., :3].astype(int) - np.array(rgb[:3])) <= tolerance, axis=-1).sum())


@pytest.mark.skipif(BROWSER is None, reason="no Chromium on PATH (.ci/run installs Debian's chromium)")
def test_the_served_url_shows_the_recording_with_both_traces_in_a_real_browser(tmp_path):
    recording, rrd = tmp_path / "run.mcap", tmp_path / "run.rrd"
    assert main(["record", "-o", str(recording), "--duration-s", "8", "--hold-s", "1"]) == 0
    assert main(["view", str(recording), "--save", str(rrd)]) == 0
    measured, model = SERIES_STYLE["measured"][1], SERIES_STYLE["model"][1]
    with served_viewer(rrd, port=_free_port_pair()) as (served, _), Chromium(BROWSER) as browser:
        page = browser.open(served.url)
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        counts: tuple[int, int] = (0, 0)
        shot = tmp_path / "viewer.png"
        while time.monotonic() < deadline:
            time.sleep(6)
            image = np.asarray(Image.open(browser.screenshot(page, shot)).convert("RGB"))
            data = image[:, int(0.4 * image.shape[1]) :]  # the plots and phase portraits (right of the 3D view)
            counts = (colour_pixels(data, measured), colour_pixels(data, model))
            if min(counts) >= MIN_PIXELS:
                break
        title = browser.evaluate(page, "document.title")
    assert title == "Rerun Viewer"
    assert min(counts) >= MIN_PIXELS, f"measured, model pixels {counts}; see {shot}"
    # the phase portraits (bottom right) show both traces too, the measured one not hidden
    bottom = image[int(0.6 * image.shape[0]) :, int(0.4 * image.shape[1]) :]
    assert colour_pixels(bottom, measured) > 300 and colour_pixels(bottom, model) > 300
