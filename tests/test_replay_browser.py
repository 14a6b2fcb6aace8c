"""The map page in real headless Chromium (Debian's chromium, driven by playwright; never a downloaded
browser): it loads without a console error and without any network request, the slider moves the
vehicle markers, and a screenshot is not blank."""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from swarmctl.cli import main

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
SITL3 = Path(__file__).resolve().parent / "data" / "logs" / "sitl3-mission"

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (.ci/run installs Debian's)")


@pytest.fixture(scope="module")
def page_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("page")
    assert main(["replay", str(SITL3), "--out", str(out), "--quiet"]) == 0
    return out / "map.html"


@pytest.fixture(scope="module")
def browser():
    playwright = pytest.importorskip("playwright.sync_api")
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def _open(browser, path: Path):
    page = browser.new_page(viewport={"width": 1100, "height": 700})
    errors: list[str] = []
    foreign: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))

    def route(r):
        if r.request.url.startswith(("file:", "data:")):
            r.continue_()
        else:
            foreign.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    page.goto(path.as_uri())
    page.wait_for_function("window.replay !== undefined && window.replay.markers().length > 0")
    return page, errors, foreign


def test_the_page_loads_offline_and_the_slider_moves_the_vehicles(browser, page_file):
    page, errors, foreign = _open(browser, page_file)
    frames = page.evaluate("window.replay.frames")
    assert frames == 26
    before = page.evaluate("window.replay.markers()")
    page.locator("#slider").fill(str(frames - 1))
    assert page.evaluate("window.replay.frame") == frames - 1
    after = page.evaluate("window.replay.markers()")
    moved = [np.hypot(a["x"] - b["x"], a["y"] - b["y"]) for a, b in zip(before, after)]
    assert max(moved) > 20  # pixels: the vehicles flew several cells
    assert page.locator("#frame").inner_text().startswith("step 25")
    assert "3 of 3 targets found" in page.locator("#counts").inner_text()
    page.locator("#slider").fill("0")
    page.locator("#play").click()
    page.wait_for_function("window.replay.frame >= 3")  # playing moves the slider on
    page.locator("#play").click()
    assert page.locator("#play").inner_text() == "Play"
    shot = page.screenshot()
    from PIL import Image

    pixels = np.asarray(Image.open(io.BytesIO(shot)).convert("RGB")).reshape(-1, 3)
    colours = np.unique(pixels[:: max(1, len(pixels) // 20000)], axis=0)
    assert len(colours) > 20 and pixels.std() > 10  # drawn, not blank
    assert errors == [] and foreign == []


def test_knowledge_of_one_vehicle_is_a_part_of_everyones(browser, page_file):
    page, errors, foreign = _open(browser, page_file)
    page.locator("#slider").fill("25")
    together = int(page.locator("#counts").inner_text().split("; ")[1].split()[0])
    page.locator("#knowledge").select_option("0")
    alone = int(page.locator("#counts").inner_text().split("; ")[1].split()[0])
    assert 0 < alone < together
    page.locator("#knowledge").select_option("none")
    assert "cells explored" not in page.locator("#counts").inner_text()
    assert errors == [] and foreign == []


def test_a_page_with_only_the_swarms_knowledge_offers_no_per_vehicle_choice(browser, tmp_path, monkeypatch):
    from swarmctl.replay import page as page_module
    from swarmctl.replay.recording import load

    monkeypatch.setattr(page_module, "MAX_KNOWLEDGE_VALUES", 1)  # as for a grid too large to send per vehicle
    path = page_module.write_page(load(SITL3), tmp_path / "map.html")
    page, errors, foreign = _open(browser, path)
    values = page.eval_on_selector_all("#knowledge option", "os => os.map(o => o.value)")
    assert values == ["all", "none"]
    page.locator("#slider").fill("25")
    assert "cells explored" in page.locator("#counts").inner_text()
    assert errors == [] and foreign == []
