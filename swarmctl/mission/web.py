"""The live map page's server (`--web`): aiohttp on the controller's own event loop.

GET `/` is the page (swarmctl.mission.web_page), `/draw.js` the renderer it shares with the replay's
map.html, `/live/setup` the mission's fixed parts (grid, area, vehicles) and `/live/state` what it is
doing now (polled by the page; `?vehicle=I` the cells that vehicle explored, `?tracks=1` every track
so far). POST `/control` takes the operator's orders, `{"action": "pause" | "resume" | "end" | "home" |
"confirm" | "reject", "vehicle": NAME, "cell": [X, Y]}`, through the controller's own paths: the stop
flag Ctrl-C sets, the pause the rounds obey, a vehicle sent home between rounds, the finds the
policy, the hover rule and the finish line leave out (MissionState.judge); each is recorded
(`operator`, `source: "web"`).

Nobody else gets the hand: every request other than GET and HEAD needs the run's token (the
`X-Swarmctl-Token` header) and, when it comes from a browser, the page's own origin, or gets 403
whatever its path; on loopback every request must name a loopback host (no DNS rebinding); bodies
over BODY_LIMIT get 413, malformed ones or an unknown vehicle 400, more than RATE requests a second
429. Handlers only read the mission's state and set flags, so they never hold up a decision round;
one that fails answers 500, is reported once (a `fault` event, part `web page`) and the search flies on.
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import secrets
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING

import numpy as np
import shapely
from aiohttp import web

from swarmctl.errors import InputError, printable
from swarmctl.knowledge.model import stacked_field
from swarmctl.mission.agent import State
from swarmctl.mission.state import fault_record
from swarmctl.mission.web_page import DRAW_JS, PAGE, WebSetup, live_js

if TYPE_CHECKING:
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.crew import Crew
    from swarmctl.mission.finish import FinishLine
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.state import MissionState

log = logging.getLogger(__name__)

BODY_LIMIT = 64 * 1024  # bytes of a request body; an order is a few dozen
RATE, BURST = 50.0, 100  # requests a second, and at once, before 429 (the page asks 4 times a second)
TRACK_EVERY_S = 0.5  # each vehicle's position is added to its track this often (when it moved)
TRACK_POINTS = 2000  # a track's points at most: every other one is dropped when it is full
TRACK_MOVE_DEG = 2e-6  # about 0.2 m: a position closer than this to the last is not added
STATE_CACHE_S = 0.1  # answers to /live/state are made at most this often (per vehicle chosen)
LINGER_S = 1.0  # after the mission ends the page is served this long, so an open page learns how it ended
ACTIONS = ("pause", "resume", "end", "home", "confirm", "reject")
TOKEN_HEADER = "X-Swarmctl-Token"

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class Bucket:
    """A token bucket: `rate` requests a second, `burst` at once."""

    def __init__(self, rate: float, burst: int) -> None:
        self.rate, self.burst = rate, float(burst)
        self.level, self.at = float(burst), time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.level = min(self.burst, self.level + (now - self.at) * self.rate)
        self.at = now
        if self.level < 1.0:
            return False
        self.level -= 1.0
        return True


def _rings(wkt: str) -> list[list[list[float]]]:
    """The exterior rings of a WKT polygon or multipolygon, as [lon, lat] points."""
    if not wkt:
        return []
    out = []
    for poly in shapely.get_parts(shapely.from_wkt(wkt)):
        if isinstance(poly, shapely.Polygon):
            out.append(np.round(np.asarray(poly.exterior.coords)[:, :2], 7).tolist())
    return out


def _bits(mask: np.ndarray) -> str:
    return base64.b64encode(np.packbits(mask.reshape(-1)).tobytes()).decode("ascii")


def _error(status: int, text: str) -> web.Response:
    return web.json_response({"error": text}, status=status)


class LiveSite:
    """The live page of one mission: its state, crew, finish line and grid to show, its recorder for the
    operator's orders; `setup` says where and with which token."""

    def __init__(
        self,
        setup: WebSetup,
        state: MissionState,
        crew: Crew,
        finish: FinishLine,
        grid: GeoGrid,
        rec: Recorder,
        *,
        name: str,
        subtitle: str,
        finish_text: str,
        time_limit: float,
    ) -> None:
        self.setup, self.state, self.crew, self.finish, self.grid, self.rec = setup, state, crew, finish, grid, rec
        self.name, self.subtitle, self.finish_text, self.time_limit = name, subtitle, finish_text, time_limit
        self.bucket = Bucket(RATE, BURST)
        self.tracks: dict[str, list[list[float]]] = {}
        self.closed = False  # the mission is over (the page says how it ended)
        self.faults = 0
        self.port = setup.port
        self._cache: dict[tuple[int, bool], tuple[float, bytes]] = {}
        self._runner: web.AppRunner | None = None
        self._sampler: asyncio.Task | None = None
        self._setup_body: bytes | None = None

    # --- the server ------------------------------------------------------------------------------------
    async def start(self) -> str:
        """Serve the page; returns its address with the token in the fragment (InputError when the
        address cannot be served: the port taken, the host not this machine's)."""
        app = web.Application(client_max_size=BODY_LIMIT, middlewares=[self._gate])
        app.router.add_get("/", self._page)
        app.router.add_get("/draw.js", self._draw_js)
        app.router.add_get("/live.js", self._live_js)
        app.router.add_get("/live/setup", self._setup_json)
        app.router.add_get("/live/state", self._state_json)
        app.router.add_post("/control", self._control)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)  # no request line is logged
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.setup.host, self.setup.port)
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise InputError(
                f"--web {self.setup.host}:{self.setup.port}: cannot be served ({exc.strerror or exc}); "
                "give another port, or --web alone for a free one"
            ) from None
        self._runner = runner
        address = runner.addresses[0]
        self.port = int(address[1])
        self._sampler = asyncio.ensure_future(self._sample())
        return f"{self.base_url}/#token={self.setup.token}"

    @property
    def base_url(self) -> str:
        host = self.setup.host
        return f"http://{f'[{host}]' if ':' in host else host}:{self.port}"

    async def close(self) -> None:
        """Stop serving (the page already says how the mission ended)."""
        if self._sampler is not None:
            self._sampler.cancel()
            try:
                await self._sampler
            except (asyncio.CancelledError, Exception):
                pass
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    async def _sample(self) -> None:
        """Each vehicle's track: its position every TRACK_EVERY_S when it moved, at most TRACK_POINTS."""
        while True:
            try:
                for a in self.crew.agents:
                    pos = a.vehicle.position
                    if pos is None:
                        continue
                    track = self.tracks.setdefault(a.name, [])
                    point = [round(pos.lon, 7), round(pos.lat, 7)]
                    if track and abs(track[-1][0] - point[0]) + abs(track[-1][1] - point[1]) < TRACK_MOVE_DEG:
                        continue
                    track.append(point)
                    if len(track) > TRACK_POINTS:
                        track[:] = track[::2]
            except Exception as exc:
                self._fault(exc)
                return
            await asyncio.sleep(TRACK_EVERY_S)

    def _fault(self, exc: BaseException) -> None:
        """A failure in the page's server: reported once, and the search flies on."""
        self.faults += 1
        if self.faults > 1:
            log.debug("web page: another failure: %s: %s", type(exc).__name__, exc)
            return
        fault = fault_record(exc, "web page")
        log.error("the live page failed (%s: %s); the search goes on", fault["where"], fault["error"])
        try:
            self.rec.event("fault", **fault)
        except Exception as again:  # the recorder may be what failed: the log keeps it
            log.error("the fault was not recorded: %s: %s", type(again).__name__, again)

    # --- who may ask -----------------------------------------------------------------------------------
    def _hosts(self) -> set[str]:
        port = self.port
        names = {self.setup.host, "127.0.0.1", "localhost", "[::1]"} if self.setup.loopback else {self.setup.host}
        return {f"{n}:{port}" if not (":" in n and not n.startswith("[")) else f"[{n}]:{port}" for n in names}

    def _origin_ok(self, request: web.Request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:  # not a browser's request (a browser names the origin of every POST)
            return True
        if self.setup.loopback:
            return origin in {f"http://{h}" for h in self._hosts()}
        return origin == f"http://{request.host}"  # the page's own origin; the token is needed besides

    def _token_ok(self, request: web.Request) -> bool:
        given = request.headers.get(TOKEN_HEADER, "")
        return secrets.compare_digest(given.encode("utf-8", "replace"), self.setup.token.encode("utf-8", "replace"))

    @web.middleware
    async def _gate(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            if not self.bucket.take():
                return _error(429, "too many requests")
            if self.setup.loopback and request.host not in self._hosts():
                return _error(403, "not this page's host")
            if request.method not in ("GET", "HEAD"):
                if not self._origin_ok(request):
                    return _error(403, "another origin")
                if not self._token_ok(request):
                    return _error(403, "the controls need the page's token")
                if (request.content_length or 0) > BODY_LIMIT:
                    return _error(413, "request body too large")
            return await handler(request)
        except web.HTTPException as exc:  # aiohttp's own answers (404, 405, 413 ...), as JSON
            if exc.status < 400:
                raise
            return _error(exc.status, exc.reason)
        except Exception as exc:
            self._fault(exc)
            return _error(500, "the page's server failed; the mission flies on")

    # --- the page --------------------------------------------------------------------------------------
    async def _page(self, request: web.Request) -> web.Response:
        import html

        body = PAGE.replace("__TITLE__", html.escape(f"{printable(self.name)}: live"))
        return web.Response(text=body, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def _draw_js(self, request: web.Request) -> web.Response:
        return web.Response(text=DRAW_JS, content_type="application/javascript")

    async def _live_js(self, request: web.Request) -> web.Response:
        return web.Response(text=live_js(), content_type="application/javascript")

    async def _setup_json(self, request: web.Request) -> web.Response:
        if self._setup_body is None:
            g = self.grid
            lat, lon = g.corner_latlon()
            corners = [[float(lat[i, j]), float(lon[i, j])] for i, j in ((0, 0), (-1, 0), (-1, -1), (0, -1))]
            body = dict(
                name=printable(self.name),
                subtitle=self.subtitle,
                finish=self.finish_text,
                time_limit=self.time_limit,
                expected=self.finish.expected,
                grid=dict(w=g.width, h=g.height, corners=corners, blocked=_bits(g.blocked)),
                area=_rings(g.area_wkt),
                nofly=_rings(g.nofly_wkt),
                vehicles=[printable(a.name) for a in self.crew.agents],
            )
            encoded = json.dumps(body, allow_nan=False).encode()
            if not self.crew.agents:  # asked before the agents were opened: not kept
                return web.Response(body=encoded, content_type="application/json")
            self._setup_body = encoded
        return web.Response(body=self._setup_body, content_type="application/json")

    async def _state_json(self, request: web.Request) -> web.Response:
        which = request.query.get("vehicle")
        vehicle = -1
        if which is not None:
            if not which.isdigit() or int(which) >= len(self.crew.agents):
                return _error(400, "no such vehicle")
            vehicle = int(which)
        tracks = request.query.get("tracks") == "1"
        key = (vehicle, tracks)
        now = time.monotonic()
        cached = self._cache.get(key)
        if cached is None or now - cached[0] > STATE_CACHE_S:
            cached = (now, json.dumps(self.snapshot(vehicle, tracks), allow_nan=False).encode())
            self._cache[key] = cached
        return web.Response(body=cached[1], content_type="application/json", headers={"Cache-Control": "no-store"})

    def snapshot(self, vehicle: int = -1, tracks: bool = False) -> dict:
        """What the mission is doing now: the page's state (vehicle >= 0: that vehicle's explored cells)."""
        state, agents = self.state, self.crew.agents
        if agents:
            fields = stacked_field([a.knowledge for a in agents], "explored")
            union = np.logical_or.reduce(fields, axis=0)
            shown = fields[vehicle] if vehicle >= 0 else union
        else:
            union = shown = np.zeros((self.grid.width, self.grid.height), dtype=bool)
        self.finish.hold_cells()
        reachable = self.finish.reachable
        vehicles = []
        for a in agents:
            pos = a.vehicle.position
            v = dict(
                name=printable(a.name),
                state=str(a.state),
                cell=list(a.cell) if a.cell is not None else None,
                lat=None if pos is None else round(pos.lat, 7),
                lon=None if pos is None else round(pos.lon, 7),
                alt=None if pos is None else round(pos.rel_alt, 1),
                battery=a.battery(),
                link=a.link_text(),
                mode=printable(str(a.vehicle.mode)),
                can_go_home=a.state in (State.SEARCH, State.HOVER) and state.outcome is None,
            )
            if tracks:
                v["track"] = self.tracks.get(a.name, [])
            vehicles.append(v)
        finds = [
            dict(
                cell=list(f.cell),
                lat=round(f.lat, 7),
                lon=round(f.lon, 7),
                time_s=round(f.time_s, 1),
                vehicle=None if f.vehicle is None else printable(f.vehicle),
                judged="confirmed" if f.cell in state.confirmed else "rejected" if f.cell in state.rejected else None,
            )
            for f in sorted(self.finish.finds.values(), key=lambda f: (f.time_s, f.step, f.cell))
        ]
        return dict(
            step=state.step,
            clock=round(state.search_seconds(), 1),
            started=state.search_started is not None,
            paused=state.held,
            holding=state.holding,
            outcome=state.outcome,
            closed=self.closed,
            vehicles=vehicles,
            explored=_bits(shown),
            explored_count=int(np.count_nonzero(shown)),
            covered=[int(np.count_nonzero(union & reachable)), int(np.count_nonzero(reachable))],
            finds=finds,
            pos=self.finish.recorded_pos(),  # the search's probability of success (swarmctl.mission.probability)
            pos_goal=self.finish.goal,
        )

    # --- the operator's orders -------------------------------------------------------------------------
    async def _control(self, request: web.Request) -> web.Response:
        try:
            order = await request.json()
        except web.HTTPException:
            raise
        except (ValueError, UnicodeDecodeError):
            return _error(400, "the body is not JSON")
        if not isinstance(order, dict) or order.get("action") not in ACTIONS:
            return _error(400, f'give {{"action": one of {", ".join(ACTIONS)}}}')
        action = order["action"]
        state = self.state
        if state.outcome is not None or state.stopping:
            return _error(409, "the search has ended")
        vehicle = cell = None
        if action in ("confirm", "reject"):
            given = order.get("cell")
            if (
                not isinstance(given, list)
                or len(given) != 2
                or not all(isinstance(c, int) and not isinstance(c, bool) for c in given)
                or (given[0], given[1]) not in self.finish.finds
            ):
                return _error(400, 'no such find: give its "cell": [x, y]')
            cell = (given[0], given[1])
            state.judge(cell, action == "confirm")
        elif action == "home":
            name = order.get("vehicle")
            agent = self.crew.named(name)
            if agent is None:
                return _error(400, "no such vehicle")
            if agent.state not in (State.SEARCH, State.HOVER):
                return _error(409, f"{printable(agent.name)} is not searching ({agent.state})")
            vehicle = agent.name
            state.orders.append(("home", vehicle))
        elif action in ("pause", "resume"):
            if state.search_started is None:
                return _error(409, "the search has not started yet")
            changed = state.hold() if action == "pause" else state.resume()
            if not changed:
                return web.json_response({"ok": True, "action": action, "changed": False})
        else:
            state.stop()  # Ctrl-C's path: every vehicle gets its end action
        self._record(action, vehicle, cell)
        return web.json_response({"ok": True, "action": action, "changed": True})

    def _record(self, action: str, vehicle: str | None, cell: tuple[int, int] | None = None) -> None:
        extra: dict[str, object] = {} if vehicle is None else {"vehicle": vehicle}
        if cell is not None:
            extra["cell"] = list(cell)
        try:
            self.rec.event("operator", action=action, source="web", step=self.state.step, **extra)
        except Exception as exc:  # the order stands; the log keeps what the recording could not
            log.error("the operator's %s was not recorded: %s: %s", action, type(exc).__name__, exc)
