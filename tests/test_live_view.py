"""The live view in a real browser: headless Chromium (Debian's ``chromium-headless-shell``) driven by
playwright, software WebGL. Skipped, with the reason printed, where playwright or the browser is missing.

A short simulated run feeds the view through the runner's hooks; the test waits for the browser to connect,
takes screenshots through the DevTools protocol and checks by pixel statistics that the canvas is not blank,
and that hiding the robot and hiding the point clouds each change the picture (so both were drawn).
"""

from __future__ import annotations

import base64
import io
import random
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BROWSER = "/usr/bin/chromium-headless-shell"
ARGS = [
    "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-background-networking", "--disable-component-update", "--no-first-run",
]  # fmt: skip

# Until 2026-12-02 this module and tests/test_nodes_faults.py were xfail(strict=False) ("timing-sensitive
# on a shared 2-core machine"), which made them unable to fail. Five runs of the net, browser and fault tests
# in one session (two with -n 2 beside the heaviest property tests) all passed, so they count again.


def _browser_or_skip():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        print(f"SKIP reason: playwright is not installed ({exc})")
        pytest.skip(f"playwright is not installed ({exc})")
    path = BROWSER if Path(BROWSER).exists() else shutil.which("chromium-headless-shell")
    if not path:
        print(f"SKIP reason: no headless Chromium at {BROWSER} (apt install chromium-headless-shell)")
        pytest.skip(f"no headless Chromium at {BROWSER} (apt install chromium-headless-shell)")
    return sync_playwright, path


def _png(data: str) -> np.ndarray:
    import matplotlib.image as mpimg

    return (mpimg.imread(io.BytesIO(base64.b64decode(data)), format="png")[..., :3] * 255).astype(np.int16)


def _drawn(canvas: np.ndarray) -> bool:
    """The 3-D canvas shows a scene: varied colours, not a blank or uniform page."""
    return bool(canvas.std() > 20 and len(np.unique(canvas.reshape(-1, 3), axis=0)) > 100)


@pytest.mark.slow
def test_live_view_in_headless_chromium():
    sync_playwright, exe = _browser_or_skip()
    pytest.importorskip("viser")
    from depthguard.io.cellfile import read_cell
    from depthguard.runner import open_source
    from depthguard.runner.chain import Chain, load_cell_robot
    from depthguard.runner.run import run_chain
    from depthguard.viz.live import LiveView

    cell = read_cell(ROOT / "examples/cells/sim-hexagon.toml")
    model = load_cell_robot(cell)
    src = open_source("sim:ral-hexagon", cell, model.joint_names, quick=True)
    src.duration = 0.2
    chain = Chain(cell, src.cameras, model)
    port = random.randint(18100, 18900)
    view = LiveView(cell, model, chain.points, chain.cameras, port=port)

    class KeepOpen:  # the run closes its sinks; the page must outlive it for the browser
        def __getattr__(self, k):
            return getattr(view, k)

        def close(self):
            pass

    try:
        run_chain(cell, src, chain, sinks=[KeepOpen()])
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=exe, args=ARGS)
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(f"http://127.0.0.1:{port}")
            t0 = time.time()
            while not view.server.get_clients() and time.time() - t0 < 60:
                time.sleep(0.2)
            assert view.server.get_clients(), "the browser never connected to the view"
            page.wait_for_selector("canvas", timeout=60_000)
            cdp = page.context.new_cdp_session(page)

            def shot() -> np.ndarray:
                time.sleep(2.0)
                return _png(cdp.send("Page.captureScreenshot", {"format": "png"})["data"])

            full = shot()
            t0 = time.time()  # a loaded machine may take longer than the first 2 s to draw the scene
            while not _drawn(full[150:, :]) and time.time() - t0 < 60:
                full = shot()
            view.urdf.show_visual = False
            no_robot = shot()
            view.urdf.show_visual = True
            view.show_clouds(False)
            no_cloud = shot()
            browser.close()
    finally:
        view.close()
    canvas = full[150:, :]  # below the panels
    assert _drawn(canvas), "blank canvas"
    robot_px = np.abs(full - no_robot).sum(axis=2) > 60
    cloud_px = np.abs(full - no_cloud).sum(axis=2) > 60
    assert robot_px.sum() > 300, f"the robot changed only {robot_px.sum()} pixels"
    assert cloud_px.sum() > 3000, f"the point clouds changed only {cloud_px.sum()} pixels"
    # the robot stands at the origin, which the initial camera puts near the middle of the picture
    ys, xs = np.nonzero(robot_px)
    assert 200 < xs.mean() < 600 and 100 < ys.mean() < 500, "robot pixels not where the robot is"
    assert view.draws > 0
