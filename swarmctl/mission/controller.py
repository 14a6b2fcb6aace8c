"""The controller: one agent per vehicle, flown through connect -> preflight -> takeoff -> search ->
hover on a target -> end action, in lock-step decision rounds on one asyncio loop.

Each round, for the agents of this process that are searching:
1. merge what arrived on the knowledge channel (each agent has its own Knowledge and its own
   KnowledgeExchange: agents talk only through MAVLink TUNNEL messages, even inside one process);
2. an agent on a known target cell that no other vehicle hovers over starts hovering there;
3. the policy chooses a move for every searching agent at once (one batch);
4. the safety guard checks the moves against the grid, the blocked cells and the cells every other
   vehicle holds or moves to (refused moves become "stay" and are logged);
5. each moving vehicle gets the position target for its cell centre at the mission altitude, and
   the round waits until they arrive or the step timeout passes;
6. each vehicle that arrived somewhere new senses (its detector's report for that cell) and every
   live agent shares (a delta of new cells and its position; digests and repairs per issue 6).

The mission ends when every live vehicle hovers on a distinct target ("complete", or "partial" when
some vehicles dropped out: lost, sent home on low battery, taken over by the pilot), when the time
limit passes ("time limit"), when no vehicle is left ("failed") or when stop() is called (signals:
"interrupted"). Then every vehicle that is still in contact gets the end action: land, rtl, or
hover (vehicles hovering on a target hold there, the others return home).

Link loss: a vehicle whose heartbeats stop is marked lost and left to its own failsafe; the others
carry on and the guard keeps its last cell free. When it comes back it rejoins: it is put back in
GUIDED at the mission altitude (taking off again if it had landed), flies to the nearest free cell
and searches with the knowledge its agent kept receiving.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from swarmctl.errors import InputError
from swarmctl.geo.fence import fence_contains, fence_polygon
from swarmctl.knowledge.exchange import KnowledgeExchange
from swarmctl.knowledge.model import Knowledge
from swarmctl.mavlink.codec import distance_m
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mavlink.gcs import GcsForwarder
from swarmctl.mission.detector import SensorFeed, UdpSensorSource
from swarmctl.mission.plan import MissionPlan
from swarmctl.mission.recorder import Recorder
from swarmctl.mission.spec import VehicleSpec
from swarmctl.world.guard import SafetyGuard
from swarmctl.world.moves import MOVE_NAMES, MOVES

log = logging.getLogger(__name__)

AIRBORNE_M = 1.0  # a vehicle this high above home (or higher) is flying, not landed

# agent states
CONNECT, PREFLIGHT, TAKEOFF, SEARCH, HOVER, LOST, REJOIN, OVERRIDE, LOW_BATTERY, ENDED, FAILED = (
    "connect",
    "preflight",
    "takeoff",
    "search",
    "hover",
    "lost",
    "rejoin",
    "override",
    "low battery",
    "ended",
    "failed",
)


class Agent:
    """One vehicle's controller: its Vehicle, Knowledge, exchange, sensor feed and state."""

    def __init__(self, index: int, spec: VehicleSpec, vehicle: Any, exchange: KnowledgeExchange, feed: SensorFeed):
        self.index, self.spec, self.vehicle = index, spec, vehicle
        self.exchange, self.feed = exchange, feed
        self.knowledge: Knowledge = exchange.knowledge
        self.state = "new"
        self.cell: tuple[int, int] | None = None
        self.steps = 0
        self.distance = 0.0
        self.refused = 0
        self.timeouts = 0
        self.end_action: str | None = None
        self.end_state: str | None = None
        self.error: str | None = None
        self._last_fix: tuple[float, float] | None = None
        self.saw_loss = False  # the link was lost since the agent last looked (even briefly)
        self.pilot_since: float | None = None  # when the vehicle was first seen in a pilot's mode
        self._accepted = 0
        self.rejoin_task: asyncio.Task | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def live(self) -> bool:
        return self.state in (SEARCH, HOVER, REJOIN)

    @property
    def targets_known(self) -> int:
        return len(self.knowledge.targets)

    def battery(self) -> int | None:
        try:
            return self.vehicle.battery_remaining
        except Exception:
            return None

    def link_text(self) -> str:
        try:
            return "lost" if self.vehicle.lost else "ok"
        except Exception:
            return "?"

    def track(self) -> None:
        """Accumulate the horizontal distance flown from telemetry."""
        pos = self.vehicle.position
        if pos is None:
            return
        if self._last_fix is not None and pos.rel_alt > 0.5:
            self.distance += distance_m(self._last_fix[0], self._last_fix[1], pos.lat, pos.lon)
        self._last_fix = (pos.lat, pos.lon)

    def received_since(self) -> int:
        total = sum(self.exchange.codec.accepted.values())
        new, self._accepted = total - self._accepted, total
        return new


class _TapSocket:
    """Wraps a KnowledgeExchange's socket so the recorder sees every datagram in and out."""

    def __init__(self, sock: Any, recorder: Recorder):
        self._sock, self._rec = sock, recorder

    def sendto(self, data: bytes, addr: Any) -> int:
        self._rec.datagram(data)
        return self._sock.sendto(data, addr)

    def recvfrom(self, size: int) -> tuple[bytes, Any]:
        data, addr = self._sock.recvfrom(size)
        self._rec.datagram(data)
        return data, addr

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


class Controller:
    """Flies one mission (ground mode: every vehicle of the plan; onboard mode: a plan of one)."""

    def __init__(
        self,
        plan: MissionPlan,
        recorder: Recorder,
        *,
        view: Callable[[Controller], None] | None = None,
    ):
        self.plan = plan
        self.rec = recorder
        self.view = view
        self.grid = plan.grid
        self.guard = SafetyGuard(self.grid.blocked, plan.spec.mission.altitude)
        self.fence = fence_polygon(self.grid) if plan.spec.mission.fence else None  # (lat, lon) vertices
        self.policy = plan.policy
        self.agents: list[Agent] = []
        self.links: dict[str, Any] = {}  # connection -> MavlinkLink, shared by the vehicles on it
        self.connector: Any = None  # swarmctl.mavlink.connect.Connector, made by _open
        self.mission_error: InputError | None = None  # what stopped the mission: raised by run()
        self.sources: list[UdpSensorSource] = []
        gcs = plan.spec.mission.gcs
        self.gcs = GcsForwarder(gcs.host, gcs.port) if gcs is not None else None
        self.step = 0
        self.outcome: str | None = None
        self.started = time.monotonic()
        self.search_started: float | None = None
        self.ended: float | None = None
        self.decide_times: list[float] = []
        self.round_times: list[float] = []
        self.wait_times: list[float] = []  # per round: waiting for vehicles to arrive and for detectors
        self.cpu_times: list[float] = []  # per round: CPU time of the controller's loop thread
        self._stop = asyncio.Event()
        self._takeoff = asyncio.Semaphore(plan.spec.flight.takeoff_at_once)
        self._link_seq: dict[tuple[int, int], int] = {}
        self.lost_packets: Counter[int] = Counter()

    # --- public ----------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the mission to end now (Ctrl-C, SIGTERM): end actions follow, recording is closed."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    async def run(self) -> str:
        """Fly the mission; returns the outcome ("complete", "time limit", "failed", "interrupted")."""
        self.rec.event(
            "mission",
            name=self.plan.spec.mission.name,
            policy=self.plan.policy.spec,
            altitude=self.plan.spec.mission.altitude,
            end_action=self.plan.spec.mission.end_action,
            grid=[self.grid.width, self.grid.height],
            vehicles=[v.name for v in self.plan.spec.vehicles],
            fence=self.fence,
        )
        try:
            await self._open()
            await self._start_all()
            if not self.stopping:
                await self._search()
        except asyncio.CancelledError:
            self.outcome = "interrupted"
            await asyncio.shield(self._finish_safely())
            raise
        await self._finish_safely()
        if self.mission_error is not None:
            raise self.mission_error  # bad input found while flying: the mission file must change
        return self.outcome or "failed"

    # --- set-up ----------------------------------------------------------------------------------------
    async def _open(self) -> None:
        """One agent per vehicle of this process; the vehicles are connected (and their autopilots
        identified) by _start."""
        from swarmctl.mavlink.connect import Connector, NotConnected

        plan, w, h = self.plan, self.grid.width, self.grid.height
        self.connector = Connector(
            self.links,
            signing_key=plan.signing_key,
            telemetry_hz=plan.spec.flight.telemetry_hz,
            on_open=self._watch_link,
            source=str(plan.mission_file or "the mission"),
        )
        for i, spec in enumerate(plan.spec.vehicles):
            if plan.only is not None and i not in plan.only:
                continue
            self.connector.expect(spec.connection)
            feed = SensorFeed(i, plan.spec.mission.id, w, h)
            if i in plan.detectors:
                socket = plan.detectors[i]
                self.sources.append(UdpSensorSource(feed, socket.host, socket.port).start())
            channel = plan.spec.knowledge.channel
            exchange = KnowledgeExchange(
                Knowledge(w, h, vehicle_id=i),
                plan.spec.mission.id,
                (channel.host, channel.port),
                system_id=spec.sysid,
                digest_every=plan.spec.knowledge.digest_every,
                push=plan.spec.knowledge.push,
            )
            exchange.sock = _TapSocket(exchange.sock, self.rec)
            self.agents.append(Agent(i, spec, NotConnected(spec.name), exchange, feed))

    def _watch_link(self, link: Any) -> None:
        """A link the connector opened: record it, count its losses, follow its vehicles, forward it."""
        self.rec.tap_link(link)
        link.add_listener(self._count_gaps)
        link.on_link_change(self._link_change)
        if self.gcs is not None:
            link.add_listener(self.gcs.forward)

    async def _connect(self, a: Agent) -> None:
        """Connect the agent's vehicle with the driver its autopilot reports (see mavlink/connect.py). A
        vehicle that disagrees with the mission file (AutopilotMismatch, an InputError) stops the mission;
        the others get their end action."""
        spec = a.spec
        try:
            vehicle = await self.connector.connect(
                spec.connection,
                spec.sysid,
                name=spec.name,
                autopilot=spec.autopilot,
                timeout=self.plan.spec.timing.connect_timeout,
            )
        except InputError as exc:
            a.error = str(exc)
            self._state(a, FAILED, error=a.error)
            if self.mission_error is None:
                self.mission_error, self.outcome = exc, "failed"
            self.stop()
            return
        a.vehicle = vehicle
        vehicle.add_listener(a.feed.listener(spec.sysid))  # the detector's TUNNEL reports, where they come

    def _count_gaps(self, msg: Any) -> None:
        """MAVLink sequence gaps per sender: packets lost on the way to us."""
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        seq = msg.get_seq()
        last = self._link_seq.get(key)
        if last is not None:
            gap = (seq - last - 1) % 256
            if gap < 128:  # a larger jump is a reboot or reordering, not loss
                self.lost_packets[key[0]] += gap
        self._link_seq[key] = seq

    def _link_change(self, sysid: int, event: str) -> None:
        self.rec.event("link", sysid=sysid, change=event)
        if event == "lost":
            for a in self.agents:
                if a.spec.sysid == sysid:
                    a.saw_loss = True

    async def _start_all(self) -> None:
        await asyncio.gather(*(self._start(a) for a in self.agents))

    async def _start(self, a: Agent) -> None:
        plan = self.plan
        try:
            self._state(a, CONNECT)
            await self._until_stopped(self._connect(a))
            if self.stopping:
                return
            self._state(a, PREFLIGHT)
            await self._until_stopped(a.vehicle.wait_ready(plan.spec.timing.ready_timeout))
            battery = a.battery()
            needed = plan.spec.battery.takeoff_min
            if battery is not None and battery < needed:
                raise MavlinkError(f"{a.name}: battery {battery} % is below the {needed} % needed to start")
            home = a.vehicle.home
            if home is None:
                raise MavlinkError(f"{a.name}: no home position")
            start = self.grid.latlon_to_cell(home.lat, home.lon)
            if not self.grid.in_grid(*start):
                raise MavlinkError(f"{a.name}: home {home.lat:.6f},{home.lon:.6f} is outside the grid")
            if self.fence is not None:
                await self._upload_fence(a, home)
            async with self._takeoff:
                if self.stopping:
                    return
                self._state(a, TAKEOFF)
                await self._until_stopped(
                    a.vehicle.arm_and_takeoff(plan.spec.mission.altitude, plan.spec.timing.takeoff_timeout)
                )
                if self.stopping:
                    return
                # the first cell: the home cell, or the nearest free one nobody holds yet
                cell = self._nearest_free(start, exclude=a)
                await self._fly(a, cell, plan.spec.timing.takeoff_timeout)
            a.cell = cell
            await self._sense_and_share(a, moved=True, since=0.0)
            self._state(a, SEARCH)
        except (TimeoutError, MavlinkError) as exc:
            a.error = str(exc)
            self._state(a, FAILED, error=str(exc))

    async def _upload_fence(self, a: Agent, home: Any) -> None:
        """The mission's fence to the vehicle, before it takes off (preflight, and again before a vehicle
        on the ground rejoins). A vehicle whose home is outside the fence, or that does not take the
        fence, does not fly (the others do)."""
        fence = self.fence
        assert fence is not None
        if not fence_contains(fence, home.lat, home.lon):
            why = (
                f"{a.name}: home {home.lat:.6f},{home.lon:.6f} is outside the fence (the search area's "
                "boundary); launch it inside the area, or fly without fence"
            )
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=False, error=why)
            raise MavlinkError(why)
        try:
            await self._until_stopped(a.vehicle.upload_fence(fence))
        except (TimeoutError, MavlinkError) as exc:
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=False, error=str(exc))
            raise MavlinkError(f"{exc}; without its fence {a.name} does not take off") from None
        if not self.stopping:
            self.rec.event("fence", vehicle=a.name, sysid=a.spec.sysid, uploaded=True, vertices=len(fence))

    async def _until_stopped(self, coro: Any) -> Any:
        """Await coro unless stop() is called first (then coro is cancelled)."""
        task = asyncio.ensure_future(coro)
        stopper = asyncio.ensure_future(self._stop.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            await _cancel(task)
            return None
        return task.result()

    def _state(self, a: Agent, state: str, **extra: Any) -> None:
        if a.state != state or extra:
            self.rec.event("state", vehicle=a.name, sysid=a.spec.sysid, state=state, cell=a.cell, **extra)
        a.state = state

    # --- cells -----------------------------------------------------------------------------------------
    def _held(self, exclude: Agent | None = None) -> set[tuple[int, int]]:
        held = {a.cell for a in self.agents if a is not exclude and a.cell is not None and a.state != FAILED}
        for a in self.agents:  # vehicles of other processes, known through the knowledge channel
            for v, p in a.knowledge.peers.items():
                if not self._ours(v) and p.cell is not None:
                    held.add(p.cell)
        return held

    def _ours(self, vehicle_index: int) -> bool:
        return any(a.index == vehicle_index for a in self.agents)

    def _nearest_free(self, start: tuple[int, int], exclude: Agent | None = None) -> tuple[int, int]:
        held = self._held(exclude)
        w, h = self.grid.width, self.grid.height
        xs, ys = np.meshgrid(np.arange(w), np.arange(h), indexing="ij")
        d = (xs - start[0]) ** 2 + (ys - start[1]) ** 2
        d = np.where(self.grid.blocked, np.iinfo(np.int64).max, d).astype(np.int64)
        for c in held:
            d[c] = np.iinfo(np.int64).max
        flat = int(np.argmin(d))
        if d.flat[flat] == np.iinfo(np.int64).max:
            raise MavlinkError("no free cell left to fly to")
        return (flat // h, flat % h)

    # --- flying ----------------------------------------------------------------------------------------
    async def _fly(self, a: Agent, cell: tuple[int, int], timeout: float) -> bool:
        """Send the position target for the cell centre at the mission altitude; wait until reached."""
        if self.grid.blocked[cell]:  # the guard never lets this happen; defence in depth
            raise MavlinkError(f"{a.name}: refusing a setpoint in blocked cell {cell}")
        lat, lon = self.grid.cell_to_latlon(*cell)
        await a.vehicle.goto(lat, lon, self.guard.setpoint_altitude())
        # wait until reached, but give up at once when the link is lost or the mission is stopped
        task = asyncio.ensure_future(a.vehicle.wait_reached(self.plan.spec.flight.reach_tolerance, timeout))
        try:
            while not task.done():
                if a.vehicle.lost or self.stopping:
                    return False
                await asyncio.wait({task}, timeout=0.1)
            return task.exception() is None
        finally:
            if not task.done():
                await _cancel(task)
            elif (
                not task.cancelled() and task.exception() is not None and not isinstance(task.exception(), MavlinkError)
            ):
                raise task.exception()

    async def _sense_and_share(self, a: Agent, moved: bool, since: float) -> list[tuple[int, int]]:
        """Sense (when the vehicle reached a new cell) and publish; returns the targets it saw."""
        kn, ex = a.knowledge, a.exchange
        on_target = a.state == HOVER
        found: list[tuple[int, int]] = []
        if moved and a.cell is not None:
            report = await a.feed.wait_report(
                a.cell, since, self.plan.spec.timing.sense_timeout, abort=lambda: a.vehicle.lost or self.stopping
            )
            if report is None:
                self.rec.event("no_report", vehicle=a.name, cell=a.cell, step=self.step)
                ex.step(self.step, a.cell, on_target)
            else:
                found = [tuple(int(v) for v in t) for t in report.targets]
                fresh = [t for t in found if t not in kn.targets]
                ex.step(
                    self.step,
                    a.cell,
                    on_target,
                    report.cells,
                    report.phi,
                    report.obstacle,
                    targets=np.array(fresh, dtype=np.int64).reshape(-1, 2) if fresh else None,
                )
                if fresh:
                    self.rec.event(
                        "targets",
                        vehicle=a.name,
                        cells=fresh,
                        step=self.step,
                        latlon=[self.grid.cell_to_latlon(*c) for c in fresh],
                    )
        elif a.cell is not None:
            ex.step(self.step, a.cell, on_target)
        return found

    # --- the search ------------------------------------------------------------------------------------
    async def _search(self) -> None:
        plan = self.plan
        self.search_started = time.monotonic()
        while True:
            t0, cpu0 = time.monotonic(), time.thread_time()
            for a in self.agents:
                a.exchange.poll(0.0)
                a.track()
            self._update_states()
            if self.stopping:
                self.outcome = "interrupted"
                return
            live = [a for a in self.agents if a.live]
            if not live and not any(a.state == LOST for a in self.agents):
                self.outcome = "failed"
                return
            if live and all(a.state == HOVER for a in live) and self._others_hovering():
                cells = [a.cell for a in live]
                if len(set(cells)) == len(cells):
                    # complete when every vehicle is hovering on a target; partial when some dropped out
                    self.outcome = "complete" if len(live) == len(self.agents) else "partial"
                    return
            if time.monotonic() - self.search_started > plan.spec.timing.time_limit:
                self.outcome = "time limit"
                return
            moved = await self._round()
            self.round_times.append(time.monotonic() - t0)
            self.cpu_times.append(time.thread_time() - cpu0)
            if self.view is not None:
                self.view(self)
            # nobody moved (all staying or waiting): do not spin faster than 10 rounds a second
            wait = max(plan.spec.timing.step_period, 0.0 if moved else 0.1) - (time.monotonic() - t0)
            if wait > 0:
                try:
                    await asyncio.wait_for(self._stop.wait(), wait)
                except TimeoutError:
                    pass
            elif not live:
                await asyncio.sleep(0.2)  # everyone is lost: wait for them without spinning

    def _pilot_has_it(self, a: Agent) -> bool:
        """The pilot took over: the vehicle reports a pilot's mode (its autopilot's is_pilot_mode), and
        has reported one for the autopilot's mode_debounce_s (a mode report may lag behind the vehicle)."""
        info = a.vehicle.autopilot_info
        if info is None or not info.is_pilot_mode(a.vehicle.mode):
            a.pilot_since = None
            return False
        now = time.monotonic()
        if a.pilot_since is None:
            a.pilot_since = now
        return now - a.pilot_since >= info.mode_debounce_s

    def _others_hovering(self) -> bool:
        """Onboard mode: every vehicle of the mission flown by another process is known (through the
        knowledge channel) to hover on a target of its own. Always true in ground mode."""
        mine = {a.cell for a in self.agents if a.state == HOVER}
        for v in range(len(self.plan.spec.vehicles)):
            if self._ours(v):
                continue
            known = [a.knowledge.positions.get(v) for a in self.agents]
            known = [p for p in known if p is not None]
            if not known:
                return False
            newest = max(known, key=lambda p: p.order())
            if not newest.on_target or newest.cell in mine:
                return False
        return True

    def _update_states(self) -> None:
        for a in self.agents:
            lost = a.vehicle.lost
            if a.state in (SEARCH, HOVER, REJOIN) and (lost or a.saw_loss):
                a.saw_loss = False
                if a.rejoin_task is not None:
                    a.rejoin_task.cancel()
                    a.rejoin_task = None
                self._state(a, LOST, last_cell=a.cell)
                continue
            if a.state == LOST and not lost:
                self._state(a, REJOIN)
                a.rejoin_task = asyncio.ensure_future(self._rejoin(a))
                continue
            if a.state in (SEARCH, HOVER) and self._pilot_has_it(a):
                self._state(a, OVERRIDE, mode=a.vehicle.mode)  # the pilot took over: stop commanding it
                a.cell = None
                continue
            battery = a.battery()
            if a.state == SEARCH and battery is not None and battery < self.plan.spec.battery.return_below:
                self._state(a, LOW_BATTERY, battery=battery)
                a.end_action = "rtl"
                asyncio.ensure_future(self._quietly(a.vehicle.rtl()))
                a.cell = None
                continue
            if a.state == SEARCH and a.cell is not None and a.cell in a.knowledge.targets:
                hovering = {b.cell for b in self.agents if b is not a and b.state == HOVER}
                hovering |= {p.cell for v, p in a.knowledge.peers.items() if p.on_target and not self._ours(v)}
                if a.cell not in hovering:
                    self._state(a, HOVER)
                    a.exchange.step(self.step, a.cell, True)  # tell the others this target is taken

    async def _quietly(self, coro: Any) -> None:
        try:
            await coro
        except (TimeoutError, MavlinkError) as exc:
            log.warning("%s", exc)

    async def _rejoin(self, a: Agent) -> None:
        plan = self.plan
        try:
            pos = a.vehicle.position
            if a.vehicle.armed and pos is not None and pos.rel_alt > AIRBORNE_M:
                # still in the air, perhaps returning or landing on its failsafe: take it back there
                await a.vehicle.resume()
            else:
                if self.fence is not None:  # a rebooted ArduPilot keeps its fence but has it off again
                    await self._until_stopped(a.vehicle.wait_ready(plan.spec.timing.ready_timeout))
                    if a.vehicle.home is None:
                        raise MavlinkError(f"{a.name}: no home position")
                    await self._upload_fence(a, a.vehicle.home)
                async with self._takeoff:
                    await a.vehicle.arm_and_takeoff(plan.spec.mission.altitude, plan.spec.timing.takeoff_timeout)
            pos = a.vehicle.position
            here = self.grid.latlon_to_cell(pos.lat, pos.lon) if pos is not None else a.cell
            if here is None or not self.grid.in_grid(*here):
                here = a.cell or (0, 0)
            a.cell = None
            cell = self._nearest_free(here, exclude=a)
            a.cell = cell
            since = time.monotonic()
            await self._fly(a, cell, plan.spec.timing.step_timeout * 3)
            await self._sense_and_share(a, moved=True, since=since)
            self._state(a, SEARCH, rejoined=True)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - a task that dies silently would leave the vehicle in REJOIN
            if not isinstance(exc, (MavlinkError, asyncio.TimeoutError)):
                log.exception("%s: rejoining failed", a.name)
            a.error = str(exc) or type(exc).__name__
            self._state(a, FAILED, error=a.error)
        finally:
            a.rejoin_task = None

    async def _round(self) -> bool:
        """One decision round; True when some vehicle moved."""
        plan = self.plan
        searching = [a for a in self.agents if a.state == SEARCH]
        t = time.monotonic()
        choices = self.policy.choose([a.knowledge for a in searching], self.step, len(plan.spec.vehicles))
        self.decide_times.append(time.monotonic() - t)
        proposed = {
            a.index: (a.cell[0] + int(MOVES[c.move][0]), a.cell[1] + int(MOVES[c.move][1]))
            for a, c in zip(searching, choices)
        }
        # guard every vehicle this process knows of; vehicles not searching stay where they are
        order = [a for a in self.agents if a.cell is not None and a.state != FAILED]
        current = [a.cell for a in order]
        wanted = [proposed.get(a.index, a.cell) for a in order]
        outside = sorted(self._held() - set(current))  # other processes' vehicles: they stay
        decisions = self.guard.guard_moves(
            np.array(current + outside, dtype=np.int64).reshape(-1, 2),
            np.array(wanted + outside, dtype=np.int64).reshape(-1, 2),
        )
        guarded = {a.index: d for a, d in zip(order, decisions)}
        self.step += 1
        moves: list[tuple[Agent, tuple[int, int]]] = []
        records = []
        for a, c in zip(searching, choices):
            d = guarded[a.index]
            if d.refused:
                a.refused += 1
                self.rec.event(
                    "refused", vehicle=a.name, step=self.step, cell=a.cell, proposed=proposed[a.index], reason=d.refused
                )
            if d.cell != a.cell:
                moves.append((a, d.cell))
            a.steps += 1
            records.append(
                dict(
                    vehicle=a.name,
                    sysid=a.spec.sysid,
                    cell=a.cell,
                    obs=c.obs_digest,
                    q=c.q,
                    move=MOVE_NAMES[c.move],
                    guarded=MOVE_NAMES[_move_index(a.cell, d.cell)],
                    refused=d.refused,
                    received=a.received_since(),
                )
            )
            if c.by:  # the move came from a planner, not from the Q-values recorded
                records[-1]["by"] = c.by
        since = time.monotonic()
        reached = await asyncio.gather(*(self._fly(a, cell, plan.spec.timing.step_timeout) for a, cell in moves))
        waited = time.monotonic() - since
        for (a, cell), ok in zip(moves, reached):
            if not ok:
                a.timeouts += 1
                self.rec.event("step_timeout", vehicle=a.name, step=self.step, cell=cell)
            a.cell = cell  # the cell is claimed either way; the vehicle keeps flying there
        moved = {a.index for a, _ in moves}
        live = [a for a in self.agents if a.state in (SEARCH, HOVER)]
        t = time.monotonic()
        await asyncio.gather(*(self._sense_and_share(a, a.index in moved, since) for a in live))
        self.wait_times.append(waited + time.monotonic() - t)
        others = [
            dict(vehicle=a.name, sysid=a.spec.sysid, state=a.state, cell=a.cell, received=a.received_since())
            for a in self.agents
            if a not in searching
        ]
        self.rec.event(
            "step", step=self.step, vehicles=records, others=others, decide_ms=round(self.decide_times[-1] * 1000, 3)
        )
        self.rec.knowledge(self.step, [(a.name, a.knowledge) for a in self.agents])
        return bool(moves)

    # --- the end ---------------------------------------------------------------------------------------
    async def _finish_safely(self) -> None:
        try:
            await self._finish()
        finally:
            await self._close()

    async def _finish(self) -> None:
        if self.outcome is None:
            self.outcome = "interrupted" if self.stopping else "failed"
        self.ended = time.monotonic()
        for a in self.agents:
            if a.rejoin_task is not None:
                a.rejoin_task.cancel()
        self.rec.event("end", outcome=self.outcome, step=self.step)
        await asyncio.gather(*(self._end_action(a) for a in self.agents))
        if self.view is not None:
            self.view(self)

    async def _end_action(self, a: Agent) -> None:
        plan = self.plan
        if a.state in (FAILED, CONNECT, PREFLIGHT) and not a.vehicle.armed:
            a.end_state = a.state
            return
        if a.state == LOST or a.vehicle.lost:
            a.end_state = "lost (left to its failsafe)"
            self.rec.event("end_action", vehicle=a.name, action="none: link lost")
            return
        if a.state == OVERRIDE:
            a.end_state = f"pilot ({a.vehicle.mode})"
            return
        action = plan.spec.mission.end_action
        if action == "hover" and a.state != HOVER:
            action = "rtl"  # only vehicles on a target hold; the others come home
        if a.state == LOW_BATTERY:
            action = "rtl"
        a.end_action = action
        self.rec.event("end_action", vehicle=a.name, action=action, cell=a.cell)
        try:
            if action == "land":
                await a.vehicle.land()
            elif action == "rtl":
                await a.vehicle.rtl()
            if action in ("land", "rtl") and plan.spec.timing.end_timeout > 0:
                await a.vehicle.wait_landed(plan.spec.timing.end_timeout)
                a.end_state = "landed at home" if action == "rtl" else "landed"
            else:
                a.end_state = "hovering on target" if a.state == HOVER else "hovering"
        except (TimeoutError, MavlinkError) as exc:
            a.end_state = f"end action failed: {exc}"
            self.rec.event("end_action_failed", vehicle=a.name, error=str(exc))
        self._state(a, ENDED, end_state=a.end_state)

    async def _close(self) -> None:
        for s in self.sources:
            s.close()
        for a in self.agents:
            try:
                await a.vehicle.close()
            except Exception as exc:  # closing must not hide the mission's result
                log.warning("%s: close failed: %s", a.name, exc)
            a.exchange.close()
        for link in self.links.values():
            await link.close()
        if self.gcs is not None:
            self.gcs.close()

    def overhead_ms(self) -> dict:
        """Per decision round (ms): the policy, the CPU time of the controller's loop thread, the whole
        round, and the controller's own part of it in wall time (the round minus the time spent waiting
        for vehicles to arrive and for detector reports)."""
        n = min(len(self.round_times), len(self.wait_times))
        if not n:
            return dict(rounds=0)
        rounds, waits = np.array(self.round_times[:n]), np.array(self.wait_times[:n])
        own = np.maximum(rounds - waits, 0.0)
        return dict(
            rounds=n,
            decide_mean=round(1000 * float(np.mean(self.decide_times)), 3),
            cpu_mean=round(1000 * float(np.mean(self.cpu_times)), 3),
            round_mean=round(1000 * float(rounds.mean()), 3),
            controller_mean=round(1000 * float(own.mean()), 3),
            controller_p95=round(1000 * float(np.percentile(own, 95)), 3),
        )

    def summary(self, extra: dict | None = None) -> dict:
        now = self.ended or time.monotonic()
        found: dict[tuple[int, int], int] = {}
        for a in self.agents:
            for c, s in a.knowledge.targets.items():
                found[c] = min(found.get(c, s), s)
        vehicles = []
        for a in self.agents:
            c = a.exchange.counters()
            vehicles.append(
                dict(
                    name=a.name,
                    sysid=a.spec.sysid,
                    autopilot=a.vehicle.autopilot,  # what the vehicle reported (None: never connected)
                    final_state=a.state,
                    end_action=a.end_action,
                    end_state=a.end_state,
                    cell=a.cell,
                    steps=a.steps,
                    distance_m=round(a.distance, 1),
                    refused_moves=a.refused,
                    step_timeouts=a.timeouts,
                    sensor_reports=a.feed.reports,
                    error=a.error,
                    knowledge_sent=c.get("sent_packets", 0),
                    knowledge_received=c.get("received_packets", 0),
                    knowledge_rejected=c.get("rejected", 0),
                    mavlink_lost=self.lost_packets.get(a.spec.sysid, 0),
                )
            )
        links = [
            dict(connection=str(k), sent=v.stats.sent, received=v.stats.received, bad_data=v.stats.bad_data)
            for k, v in self.links.items()
        ]
        hovering = [a.cell for a in self.agents if a.state == HOVER or a.end_state == "hovering on target"]
        out = dict(
            mission=self.plan.spec.mission.name,
            policy=self.plan.policy.spec,
            outcome=self.outcome,
            targets_found=[
                dict(cell=list(c), lat=self.grid.cell_to_latlon(*c)[0], lon=self.grid.cell_to_latlon(*c)[1], step=s)
                for c, s in sorted(found.items())
            ],
            vehicles_on_targets=[list(c) for c in hovering if c is not None],
            time_s=round(now - self.started, 2),
            search_time_s=round(now - self.search_started, 2) if self.search_started else 0.0,
            steps=self.step,
            vehicles=vehicles,
            messages=dict(
                mavlink_sent=sum(v.stats.sent for v in self.links.values()),
                mavlink_received=sum(v.stats.received for v in self.links.values()),
                mavlink_lost=sum(self.lost_packets.values()),
                knowledge_sent=sum(v["knowledge_sent"] for v in vehicles),
                knowledge_received=sum(v["knowledge_received"] for v in vehicles),
                knowledge_rejected=sum(v["knowledge_rejected"] for v in vehicles),
            ),
            links=links,
            overhead_ms=self.overhead_ms(),
        )
        if extra:
            out.update(extra)
        return out


async def _cancel(task: asyncio.Future) -> None:
    """Cancel a task and wait for it to finish (whatever it raises on the way out)."""
    task.cancel()
    try:
        await task
    except (asyncio.CancelledError, Exception):
        pass


def _move_index(cur: tuple[int, int], new: tuple[int, int]) -> int:
    d = (new[0] - cur[0], new[1] - cur[1])
    for i, m in enumerate(MOVES):
        if (int(m[0]), int(m[1])) == d:
            return i
    return 0
