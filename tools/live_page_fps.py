"""How fast the live map page (swarmctl.mission.web_page, drawn by static/draw.js) redraws in headless
Chromium: 50 vehicles with 500-point tracks on a 100 x 100 grid, a tenth of it blocked, half of it
explored, every frame a new state as the page gets it from the controller (the explored cells decoded
and turned into an image, the table and the map redrawn).

    python tools/live_page_fps.py [--vehicles 50] [--size 100] [--frames 200]

Prints frames a second (the median of 3 runs of --frames frames). Needs Debian's chromium and
playwright, as the browser tests.
"""

from __future__ import annotations

import argparse
import base64
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmctl.mission.web_page import DRAW_JS, PAGE, live_js  # noqa: E402

ORIGIN = "http://live.test"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]


def _bits(mask: np.ndarray) -> str:
    return base64.b64encode(np.packbits(mask.reshape(-1)).tobytes()).decode("ascii")


def synthetic(vehicles: int, size: int, seed: int = 0) -> tuple[dict, dict]:
    """The page's setup and one state: a size x size grid of 10 m cells near Chicago, the vehicles
    spread over it, each with a 500-point track."""
    rng = np.random.default_rng(seed)
    lat0, lon0, dlat, dlon = 41.87, -87.64, 10 / 111_000, 10 / 83_000
    corners = [
        [lat0, lon0],
        [lat0, lon0 + size * dlon],
        [lat0 + size * dlat, lon0 + size * dlon],
        [lat0 + size * dlat, lon0],
    ]
    setup = dict(
        name="fps",
        subtitle=f"{vehicles} vehicles, {size} x {size} cells",
        finish="finish covered",
        time_limit=600.0,
        expected=None,
        grid=dict(w=size, h=size, corners=corners, blocked=_bits(rng.random((size, size)) < 0.1)),
        area=[],
        nofly=[],
        vehicles=[f"uav{i + 1}" for i in range(vehicles)],
    )
    states = []
    for i in range(vehicles):
        walk = np.cumsum(rng.normal(0, 1, (500, 2)), axis=0) + rng.uniform(0, size, 2)
        walk = np.clip(walk, 0, size)
        track = [[round(lon0 + x * dlon, 7), round(lat0 + y * dlat, 7)] for x, y in walk]
        states.append(
            dict(
                name=f"uav{i + 1}",
                state="search",
                cell=[int(walk[-1, 0]), int(walk[-1, 1])],
                lat=track[-1][1],
                lon=track[-1][0],
                alt=30.0,
                battery=90,
                link="ok",
                mode="GUIDED",
                can_go_home=True,
                track=track,
            )
        )
    explored = rng.random((size, size)) < 0.5
    state = dict(
        step=100,
        clock=60.0,
        started=True,
        paused=False,
        holding=False,
        outcome=None,
        closed=False,
        vehicles=states,
        explored=_bits(explored),
        explored_count=int(explored.sum()),
        covered=[int(explored.sum()), size * size],
        finds=[dict(cell=[1, 1], lat=lat0, lon=lon0, time_s=12.0, vehicle="uav1")],
    )
    return setup, state


MEASURE = """([frames, dlat]) => {
  const s = window.live.state;
  const t0 = performance.now();
  for (let f = 0; f < frames; f++) {
    s.vehicles.forEach(function (v, i) { v.lat += dlat * Math.sin(f + i); v.track = undefined; });
    window.live.show(s);
  }
  return frames / ((performance.now() - t0) / 1000);
}"""


def measure(vehicles: int, size: int, frames: int) -> list[float]:
    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    setup, state = synthetic(vehicles, size)
    bodies = {
        "/": ("text/html", PAGE.replace("__TITLE__", "fps")),
        "/draw.js": ("application/javascript", DRAW_JS),
        "/live.js": ("application/javascript", live_js()),
        "/live/setup": ("application/json", json.dumps(setup)),
    }

    def route(r):
        path = r.request.url[len(ORIGIN) :].split("?")[0]
        if path == "/live/state":
            return r.fulfill(content_type="application/json", body=json.dumps(dict(state, closed=True)))
        kind, body = bodies.get(path, ("text/plain", ""))
        r.fulfill(content_type=kind, body=body, status=200 if path in bodies else 404)

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.route("**/*", route)
        page.goto(ORIGIN + "/#token=x")
        page.wait_for_function(f"window.live.state && window.live.markers().length === {vehicles}")
        rates = [page.evaluate(MEASURE, [frames, 1e-6]) for _ in range(3)]
        browser.close()
    return rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--size", type=int, default=100)
    ap.add_argument("--frames", type=int, default=200)
    args = ap.parse_args()
    rates = sorted(measure(args.vehicles, args.size, args.frames))
    print(
        f"live page, {args.vehicles} vehicles on {args.size} x {args.size} cells: {rates[1]:.0f} frames a second "
        f"(median of 3 runs of {args.frames}; {', '.join(f'{r:.0f}' for r in rates)})"
    )


if __name__ == "__main__":
    main()
