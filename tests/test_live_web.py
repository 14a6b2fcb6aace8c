"""The live map page (`--web`): the demo flown with it, the page in headless Chromium (Debian's
chromium through playwright, as tests/test_replay_browser.py), its controls, and what it refuses."""

from __future__ import annotations

import json
import socket
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.mission.web import BURST, RATE
from swarmctl.mission.web_page import DRAW_JS, WebOptions, web_setup
from tests.test_replay_browser import ARGS, CHROMIUM, SITL3

TOKEN = "live-page-test-token-0123456789"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(url: str, data: bytes | None = None, headers: dict | None = None) -> tuple[int, bytes]:
    req = urllib.request.Request(url, data=data, headers=headers or {}, method="POST" if data is not None else "GET")
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def wait_until(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def test_web_options_give_an_address_and_a_token(tmp_path):
    assert web_setup(WebOptions()) is None
    alone = web_setup(WebOptions(web=""))
    assert alone is not None and (alone.host, alone.port) == ("127.0.0.1", 0) and len(alone.token) >= 32
    assert alone.token != web_setup(WebOptions(web="")).token  # a new one each run
    port = web_setup(WebOptions(web="8080"))
    assert port is not None and (port.host, port.port) == ("127.0.0.1", 8080)
    for bad in ("80:80:x", "host:", "99999", "-1"):
        with pytest.raises(InputError, match="--web"):
            web_setup(WebOptions(web=bad))
    with pytest.raises(InputError, match="--web-token-file"):
        web_setup(WebOptions(web="0.0.0.0:8080"))
    short = tmp_path / "short"
    short.write_text("abc\n")
    with pytest.raises(InputError, match="holds no token"):
        web_setup(WebOptions(web="0.0.0.0:8080", web_token_file=str(short)))
    good = tmp_path / "token"
    good.write_text(TOKEN + "\n")
    wide = web_setup(WebOptions(web="0.0.0.0:8080", web_token_file=str(good)))
    assert wide is not None and wide.token == TOKEN and not wide.loopback
    with pytest.raises(InputError, match="only --web reads it"):
        web_setup(WebOptions(web_token_file=str(good)))


def test_the_replay_page_inlines_the_live_pages_drawing_script(tmp_path):
    assert main(["replay", str(SITL3), "--out", str(tmp_path), "--quiet"]) == 0
    page = (tmp_path / "map.html").read_text(encoding="utf-8")
    assert DRAW_JS in page and "window.SwarmMap = function" in DRAW_JS


class Demo:
    """`swarmctl demo --web` flown in a thread; `swarm` is its SimSwarm once it is made."""

    def __init__(self, monkeypatch, tmp_path: Path) -> None:
        from swarmctl.sim import swarm as sim

        self.swarm = None
        self.port = free_port()
        self.folder = tmp_path / "demo"
        token_file = tmp_path / "token"
        token_file.write_text(TOKEN)
        enter = sim.SimSwarm.__enter__

        def keep(swarm):
            self.swarm = swarm
            return enter(swarm)

        monkeypatch.setattr(sim.SimSwarm, "__enter__", keep)
        args = ["demo", "--uavs", "3", "--seed", "1", "--speedup", "10", "--no-detectors", "--time-limit", "120"]
        args += ["--out", str(self.folder), "--quiet", "--web", f"127.0.0.1:{self.port}"]
        args += ["--web-token-file", str(token_file)]
        self.code: list[int] = []
        self.thread = threading.Thread(target=lambda: self.code.append(main(args)), daemon=True)
        self.thread.start()
        self.url = f"http://127.0.0.1:{self.port}"

    def state(self) -> dict:
        """The page's state now (asked again while the rate limit refuses: 429)."""
        got: list[bytes] = []

        def answered() -> bool:
            code, body = request(f"{self.url}/live/state")
            if code == 200:
                got.append(body)
            return code == 200

        wait_until(answered, 10, "the state")
        return json.loads(got[-1])

    def events(self) -> list[dict]:
        return [json.loads(line) for line in (self.folder / "events.jsonl").read_text().splitlines()]


def served(url: str) -> bool:
    try:
        return request(url)[0] == 200
    except OSError:
        return False


@pytest.fixture
def demo(monkeypatch, tmp_path):
    """The demo flying with its page; ended (as the page's End button does) whatever the test did."""
    flying = Demo(monkeypatch, tmp_path)
    yield flying
    if flying.thread.is_alive():
        order = json.dumps({"action": "end"}).encode()
        try:
            request(flying.url + "/control", order, {"X-Swarmctl-Token": TOKEN})
        except OSError:
            pass
        flying.thread.join(90)


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (.ci/run installs Debian's)")
def test_the_live_page_shows_the_search_and_its_controls_fly_it(demo):
    playwright = pytest.importorskip("playwright.sync_api")
    url = demo.url
    wait_until(lambda: served(url + "/live/state"), 60, "the live page")
    assert request(url + "/draw.js")[1].decode("utf-8") == DRAW_JS  # the replay page's renderer

    # nobody else gets the hand: refused, and nothing changes
    order = json.dumps({"action": "end"}).encode()
    assert request(url + "/control", order)[0] == 403  # no token
    assert request(url + "/anything/else", order)[0] == 403  # whatever the path
    assert request(url + "/control", order, {"X-Swarmctl-Token": "guess"})[0] == 403
    foreign = {"X-Swarmctl-Token": TOKEN, "Origin": "http://evil.example"}
    assert request(url + "/control", order, foreign)[0] == 403  # the token, from another origin
    mine = {"X-Swarmctl-Token": TOKEN, "Content-Type": "application/json"}
    assert request(url + "/control", b"{not json", mine)[0] == 400
    assert request(url + "/control", json.dumps({"action": "home", "vehicle": "nobody"}).encode(), mine)[0] == 400
    assert request(url + "/control", b"x" * 10_000_000, mine)[0] == 413
    assert request(url + "/live/state", headers={"Host": "rebound.example"})[0] == 403
    flood = [request(url + "/control", order)[0] for _ in range(150)]  # faster than the page's server takes
    assert set(flood) == {403, 429} and flood.count(429) > 20
    time.sleep(BURST / RATE)  # the time the rate limit takes to refill: the page then loads at once
    state = demo.state()
    assert state["outcome"] is None and not state["paused"]
    assert not any(e["event"] == "operator" for e in demo.events())

    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        errors: list[str] = []
        outside: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))

        def route(r):
            if r.request.url.startswith(url):
                r.continue_()
            else:
                outside.append(r.request.url)
                r.abort()

        page.route("**/*", route)
        page.goto(f"{url}/#token={TOKEN}")
        page.wait_for_function(
            "window.live.state && window.live.state.step > 0 && window.live.markers().filter(Boolean).length === 3",
            timeout=60_000,
        )
        before = page.evaluate("[window.live.markers(), window.live.state.explored_count]")
        page.wait_for_function(
            """([m, n]) => window.live.state.explored_count > n && window.live.markers().some(
                (q, i) => q && m[i] && Math.hypot(q.x - m[i].x, q.y - m[i].y) > 3)""",
            arg=before,
            timeout=30_000,
        )

        def late() -> dict:  # what a late or reloaded page starts from: every track so far
            return json.loads(request(url + "/live/state?tracks=1")[1])

        wait_until(lambda: all(len(v["track"]) >= 2 for v in late()["vehicles"]), 20, "the tracks")
        assert late()["explored_count"] > 0
        page.locator("#vehicles tbody tr").nth(0).click()  # one vehicle's explored cells, a part of everyone's
        page.wait_for_function("document.getElementById('progress').textContent.includes('explored by uav1')")
        alone = json.loads(request(url + "/live/state?vehicle=0")[1])["explored_count"]
        assert 0 < alone <= json.loads(request(url + "/live/state")[1])["explored_count"]  # (all, on an ideal bus)
        page.locator("#vehicles tbody tr").nth(0).click()
        reader = browser.new_page()  # without the token: read-only
        reader.goto(url + "/")
        reader.wait_for_function("window.live.state && window.live.state.step > 0")
        assert reader.locator("#pause").is_disabled() and reader.locator("#end").is_disabled()
        assert reader.locator("button.home").count() == 0 and "read-only" in reader.locator("#access").inner_text()
        reader.close()
        page.locator("#pause").click()
        page.wait_for_function("window.live.state.holding", timeout=30_000)
        held = time.monotonic()
        step = demo.state()["step"]
        assert demo.swarm is not None
        # no setpoint for 3 s (the time it takes is the point), while the page keeps updating
        while time.monotonic() - held < 3.0:
            assert all(m.last_setpoint <= held for m in demo.swarm.mocks)
            time.sleep(0.1)
        state = demo.state()
        assert state["step"] == step and state["paused"] and state["outcome"] is None
        page.locator("#resume").click()
        page.wait_for_function(f"window.live.state.step > {step}", timeout=30_000)
        page.locator("#vehicles tbody tr").nth(1).locator("button.home").click()  # uav2 home
        page.wait_for_function("window.live.state.vehicles[1].state === 'ended'", timeout=30_000)
        demo.swarm.mocks[1].wait_for(lambda m: m.mode_name == "RTL", 30)
        page.locator("#end").click()
        page.locator("#end").click()  # the second click ends it
        page.wait_for_function("window.live.state.outcome === 'interrupted'", timeout=30_000)
        for mock in demo.swarm.mocks:  # every vehicle home and disarmed: the end action flew
            mock.wait_for(lambda m: not m.state().armed, 60)
        page.wait_for_function("document.getElementById('banner').textContent.includes('interrupted')")
        shot = page.screenshot()
        browser.close()
    demo.thread.join(60)
    assert demo.code and errors == [] and outside == []
    assert len(shot) > 10_000
    orders = [(e["action"], e["source"]) for e in demo.events() if e["event"] == "operator"]
    assert orders == [("pause", "web"), ("resume", "web"), ("home", "web"), ("end", "web")]
    summary = json.loads((demo.folder / "summary.json").read_text())
    assert summary["outcome"] == "interrupted"
    assert [v["end_state"] for v in summary["vehicles"]] == ["landed at home"] * 3
    for path in demo.folder.iterdir():  # the token is in no file of the recording
        assert TOKEN.encode() not in path.read_bytes(), path.name
    from swarmctl.replay.page import page_data
    from swarmctl.replay.recording import load

    given = [o["text"] for o in page_data(load(demo.folder))["orders"]]  # the replay's map page lists them
    assert [t.split(" (")[0] for t in given] == ["pause", "resume", "home uav2", "end"]


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (.ci/run installs Debian's)")
def test_the_live_page_draws_50_vehicles_on_100_by_100_cells_at_20_frames_a_second():
    pytest.importorskip("playwright.sync_api")
    from tools.live_page_fps import measure

    rates = measure(50, 100, 40)
    assert sorted(rates)[1] >= 20, rates


def test_a_rejected_find_is_no_target_and_its_vehicle_searches_on(tmp_path):
    from swarmctl.mission.service import run_controller
    from swarmctl.mission.web_page import WebSetup
    from swarmctl.sim.swarm import SimSwarm, hide_targets
    from tests.mission_support import small_grid

    said: dict = {}
    mine = {"X-Swarmctl-Token": TOKEN}

    def operator(url: str) -> None:  # on the controller's loop: the operator acts from a thread
        base = url.split("#")[0]

        def state() -> dict:
            return json.loads(request(base + "live/state")[1])

        def order(**body) -> int:
            return request(base + "control", json.dumps(body).encode(), mine)[0]

        def act() -> None:
            try:
                wait_until(lambda: any(v["state"] == "hover" for v in state()["vehicles"]), 60, "a vehicle on a find")
                hovering = next(v for v in state()["vehicles"] if v["state"] == "hover")
                said["cell"] = hovering["cell"]
                said["bad"] = order(action="reject", cell=[99, 99])
                said["reject"] = order(action="reject", cell=hovering["cell"])
                wait_until(
                    lambda: next(v for v in state()["vehicles"] if v["name"] == hovering["name"])["state"] == "search",
                    20,
                    "the vehicle to search again",
                )
                said["judged"] = [f["judged"] for f in state()["finds"] if f["cell"] == hovering["cell"]]
                time.sleep(1.0)  # a second of rounds, in which nobody may park on the rejected find
            finally:
                said["end"] = order(action="end")

        threading.Thread(target=act, daemon=True).start()

    swarm = SimSwarm(small_grid(), uavs=3, seed=3, speedup=60.0)
    swarm.targets = hide_targets(swarm.grid, 2, 3, swarm.starts)  # fewer than the vehicles: never complete
    with swarm:
        plan = swarm.plan("frontier:hover=first", end_action="rtl", time_limit=60.0, takeoff_at_once=4)
        _, summary = run_controller(plan, tmp_path, None, web=WebSetup("127.0.0.1", 0, TOKEN), on_web=operator)
    assert (said["bad"], said["reject"], said["end"]) == (400, 200, 200)
    assert said["judged"] == ["rejected"] and summary["outcome"] == "interrupted"
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    at = next(i for i, e in enumerate(events) if e["event"] == "operator" and e["action"] == "reject")
    assert events[at]["cell"] == said["cell"] and events[at]["source"] == "web"
    parked = [e for e in events[at:] if e["event"] == "state" and e["state"] == "hover" and e["cell"] == said["cell"]]
    assert parked == []


def test_with_confirm_finds_the_finish_line_waits_for_the_operators_word(tmp_path):
    from swarmctl.mission.service import run_controller
    from swarmctl.mission.web_page import WebSetup
    from swarmctl.sim.swarm import SimSwarm
    from tests.mission_support import small_grid

    said: dict = {}

    def operator(url: str) -> None:  # on the controller's loop: the operator acts from a thread
        base = url.split("#")[0]

        def state() -> dict:
            return json.loads(request(base + "live/state")[1])

        def act() -> None:
            wait_until(lambda: state()["finds"], 60, "a find")
            time.sleep(1.0)  # a second of rounds with the find unconfirmed: the line is not met
            said["before"] = state()["outcome"]
            cell = state()["finds"][0]["cell"]
            body = json.dumps({"action": "confirm", "cell": cell}).encode()
            said["confirm"] = request(base + "control", body, {"X-Swarmctl-Token": TOKEN})[0]

        threading.Thread(target=act, daemon=True).start()

    with SimSwarm(small_grid(), uavs=2, seed=3, speedup=60.0) as swarm:
        settings = dict(finish="found", expected_targets=1, on_find="mark", confirm_finds=True)
        plan = swarm.plan("frontier", end_action="rtl", time_limit=60.0, takeoff_at_once=4, **settings)
        code, summary = run_controller(plan, tmp_path, None, web=WebSetup("127.0.0.1", 0, TOKEN), on_web=operator)
    assert said == {"before": None, "confirm": 200}
    assert code == 0 and summary["outcome"] == "complete" and summary["finish"]["met"]
    assert summary["search_time_s"] > summary["finds"][0]["time_s"] + 1.0
