"""The controller: one agent per vehicle, flown through connect -> preflight -> takeoff -> search ->
hover on a target -> end action, in lock-step decision rounds on one asyncio loop.

The controller builds the parts, each with only what it needs, and they own their state: the
mission's step, outcome, clock, stop flag and tasks (MissionState, state.py); the agents and what they
hold together (Crew, crew.py); connect, preflight, take-off and rejoin (Launch, launch.py); the
decision rounds (Rounds, rounds.py); flying to a cell and sensing there (Flight, flight.py); the
off-course check (Watch, watch.py); the finish line and the finds (FinishLine, finish.py); the end
actions (Ending, ending.py). This module opens the agents and their links, runs the launch and the
rounds, and ends the mission: every vehicle that is still in contact gets its end action, and the
recording gets the summary. Every task the mission starts is kept (MissionState.spawn) and finished
before the mission returns.

Link loss: a vehicle whose heartbeats stop is marked lost and left to its own failsafe; the others
carry on and the guard keeps its last cell free. When it comes back it rejoins (Launch.rejoin).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from swarmctl.geo.fence import fence_polygon
from swarmctl.mavlink.connect import Connector, NotConnected
from swarmctl.mavlink.gcs import GcsForwarder
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.crew import Crew
from swarmctl.mission.detector import SensorFeed, UdpSensorSource
from swarmctl.mission.ending import Ending
from swarmctl.mission.finish import FinishLine
from swarmctl.mission.flight import Flight
from swarmctl.mission.launch import Launch
from swarmctl.mission.plan import MissionPlan
from swarmctl.mission.recorder import Recorder
from swarmctl.mission.rounds import Rounds
from swarmctl.mission.sharing import link_outlet, make_bus, open_exchange
from swarmctl.mission.state import MissionState, fault_record
from swarmctl.mission.watch import Watch
from swarmctl.signing import signing_counts
from swarmctl.world.guard import SafetyGuard

log = logging.getLogger(__name__)


def link_signing(link: Any) -> dict:
    """A signing link's counts (frames refused unsigned or wrongly signed, bad signatures); none without a key."""
    mav = getattr(link, "mav", None)
    if getattr(link, "signing_key", None) is None or mav is None:
        return {}
    counts = signing_counts(mav)
    return dict(signing_refused=counts["refused"], signing_bad=counts["bad"])


class Controller:
    """Flies one mission (ground mode: every vehicle of the plan; onboard mode: a plan of one)."""

    def __init__(
        self,
        plan: MissionPlan,
        recorder: Recorder,
        *,
        view: Callable[[MissionState, Crew], None] | None = None,
    ):
        self.plan = plan
        self.rec = recorder
        self.view = view
        self.grid = plan.grid
        self.guard = SafetyGuard(self.grid.blocked, plan.altitude)
        self.fence = fence_polygon(self.grid) if plan.spec.mission.fence else None  # (lat, lon) vertices
        self.policy = plan.policy
        self.links: dict[str, Any] = {}  # connection -> MavlinkLink, shared by the vehicles on it
        self.connector = Connector(
            self.links,
            signing_key=plan.signing_key,
            telemetry_hz=plan.spec.flight.telemetry_hz,
            on_open=self._watch_link,
            source=str(plan.mission_file or "the mission"),
            first_link_id=None if plan.only is None else min(plan.only) % 256,  # onboard: the vehicle's index
        )
        self.sources: list[UdpSensorSource] = []
        self.bus = make_bus(plan)  # ground mode: the agents share in memory (None: onboard, the channel)
        gcs = plan.spec.mission.gcs
        self.gcs = GcsForwarder(gcs.host, gcs.port) if gcs is not None else None
        # MAVLink sequence gaps, kept for the mission's system ids only (bounded: not one entry per id heard)
        self._sysids = {v.sysid for v in plan.spec.vehicles}
        self._link_seq: dict[tuple[int, int], int] = {}
        self.lost_packets: Counter[int] = Counter()
        # the parts, each with what it needs
        spec = plan.spec
        show = self._show if view is not None else None
        self.state = MissionState()
        self.crew = Crew(len(spec.vehicles), plan.only, recorder)
        self.finish = FinishLine(plan, self.crew, self.state, recorder, self.gcs)
        self.policy.set_hold(self.finish.to_hold)  # the hover rule parks once that many targets are known
        self.policy.set_search(self.finish.probability)  # planners go where the probability is
        self.watch = Watch(self.grid, self.guard, spec.flight, recorder, self.state, self.crew)
        self.flight = Flight(
            self.grid,
            self.guard,
            plan.fov,
            spec.flight,
            spec.timing,
            recorder,
            self.state,
            self.crew,
            self.watch,
            self.finish,
        )
        self.launch = Launch(plan, self.fence, self.connector, recorder, self.state, self.crew, self.flight, show)
        self.rounds = Rounds(
            spec.timing,
            spec.battery,
            self.policy,
            self.guard,
            recorder,
            self.state,
            self.crew,
            self.watch,
            self.flight,
            self.launch,
            self.finish,
            show,
        )
        self.ending = Ending(spec.mission.end_action, plan.altitude, spec.timing, recorder, self.crew)

    # --- what callers read ------------------------------------------------------------------------------
    @property
    def agents(self) -> list[Agent]:
        return self.crew.agents

    @property
    def step(self) -> int:
        return self.state.step

    @property
    def outcome(self) -> str | None:
        return self.state.outcome

    @property
    def search_started(self) -> float | None:
        return self.state.search_started

    @property
    def ended(self) -> float | None:
        return self.state.ended

    @property
    def on_targets(self) -> list[tuple[int, int]]:
        return self.state.on_targets

    def stop(self) -> None:
        """Ask the mission to end now (Ctrl-C, SIGTERM): end actions follow, recording is closed."""
        self.state.stop()

    @property
    def stopping(self) -> bool:
        return self.state.stopping

    def overhead_ms(self) -> dict:
        """Per decision round (ms): swarmctl.mission.state.RoundTimes.overhead_ms."""
        return self.state.times.overhead_ms()

    def _show(self) -> None:
        """The live view; one that fails is reported once (a `fault` event) and turned off: a broken
        display never stops the search."""
        if self.view is None:
            return
        try:
            self.view(self.state, self.crew)
        except Exception as exc:
            self.view = None
            fault = fault_record(exc, "live view")
            log.error("the live view failed and is off (%s: %s); the search goes on", fault["where"], fault["error"])
            self._record_fault(fault)

    def _record_fault(self, fault: dict[str, str]) -> None:
        try:
            self.rec.event("fault", **fault)
        except Exception as exc:  # the recorder may be what failed: the log keeps it
            log.error("the fault was not recorded: %s: %s", type(exc).__name__, exc)

    async def run(self) -> str:
        """Fly the mission; returns the outcome ("complete", "partial", "time limit", "failed",
        "interrupted")."""
        state = self.state
        self.rec.event(
            "mission",
            name=self.plan.spec.mission.name,
            policy=self.plan.policy.spec,
            altitude=self.plan.spec.mission.altitude,
            end_action=self.plan.spec.mission.end_action,
            grid=[self.grid.width, self.grid.height],
            vehicles=[v.name for v in self.plan.spec.vehicles],
            fence=self.fence,
            finish=self.finish.rule,
            expected_targets=self.finish.expected,
            on_find=self.finish.on_find,
            **self.plan.policy.recorded(),
        )
        self.rec.plain_event("prior", **self.finish.probability.prior_record())  # once; 8 decimals, as rounded
        try:
            self._open()
            await asyncio.gather(*(self.launch.start(a) for a in self.crew.agents))
            if not state.stopping:
                await self.rounds.search()
        except asyncio.CancelledError:
            state.outcome = "interrupted"
            await asyncio.shield(self._finish_safely())
            raise
        except Exception as exc:  # a bug: the vehicles in the air still get their end action before it is raised
            state.outcome = "failed"
            state.fault = fault_record(exc, "mission")
            self._record_fault(state.fault)
            await self._finish_safely()
            raise
        await self._finish_safely()
        if state.mission_error is not None:
            raise state.mission_error  # bad input found while flying: the mission file must change
        return state.outcome or "failed"

    # --- set-up ----------------------------------------------------------------------------------------
    def _open(self) -> None:
        """One agent per vehicle of this process; the vehicles are connected (and their autopilots
        identified) by Launch.start."""
        plan, w, h = self.plan, self.grid.width, self.grid.height
        for i, spec in enumerate(plan.spec.vehicles):
            if plan.only is not None and i not in plan.only:
                continue
            self.connector.expect(spec.connection)
            feed = SensorFeed(i, plan.spec.mission.id, w, h)
            detector = plan.detectors.get(i)
            if detector is not None and not isinstance(detector, str):  # a local socket, not its link
                self.sources.append(UdpSensorSource(feed, detector.host, detector.port).start())
            exchange = open_exchange(plan, i, spec, self.rec, self.bus)
            agent = Agent(i, spec, NotConnected(spec.name), exchange, feed, detector=detector)
            if self.bus is not None:
                exchange.outlet = link_outlet(agent)  # its frames once, on its own vehicle's link
            self.crew.agents.append(agent)

    def _watch_link(self, link: Any) -> None:
        """A link the connector opened: record it, count its losses, follow its vehicles, forward it."""
        self.rec.tap_link(link)
        link.add_batch_listener(self._count_gaps)
        link.on_link_change(self._link_change)
        if self.gcs is not None:
            link.add_listener(self.gcs.forward)

    def _count_gaps(self, msgs: list) -> None:
        """MAVLink sequence gaps per sender (the mission's vehicles: their system ids, component 1 or
        whatever they send from, at most 256 entries each): packets lost on the way to us. Takes a
        link's messages a batch at a time, in the order they came."""
        sysids, seqs, lost = self._sysids, self._link_seq, self.lost_packets
        for msg in msgs:
            header = msg._header  # pymavlink's parsed header: srcSystem, srcComponent, seq
            src = header.srcSystem
            if src not in sysids:
                continue
            key, seq = (src, header.srcComponent), header.seq
            last = seqs.get(key)
            if last is not None:
                gap = (seq - last - 1) % 256
                if gap < 128:  # a larger jump is a reboot or reordering, not loss
                    lost[src] += gap
            seqs[key] = seq

    def _link_change(self, sysid: int, event: str) -> None:
        self.rec.event("link", sysid=sysid, change=event)
        if event == "lost":
            for a in self.agents:
                if a.spec.sysid == sysid:
                    a.saw_loss = True

    # --- the end ---------------------------------------------------------------------------------------
    async def _finish_safely(self) -> None:
        try:
            await self._finish()
        finally:
            await self._close()

    async def _finish(self) -> None:
        state = self.state
        if state.outcome is None:
            state.outcome = "interrupted" if state.stopping else "failed"
        state.ended = time.monotonic()
        state.on_targets = [a.cell for a in self.agents if a.state is State.HOVER and a.cell is not None]
        try:
            self.rec.ending()  # what follows is written into the space the recording kept for it
            self.finish.close(state.outcome)
            for a in self.agents:
                if a.rejoin_task is not None:
                    a.rejoin_task.cancel()
            await state.settle_tasks()
            self.rec.event("end", outcome=state.outcome, step=state.step)
        finally:  # whatever failed above, every vehicle in the air gets its end action
            await self.ending.all()
        self._show()

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

    def summary(self, extra: dict | None = None) -> dict:
        now = self.state.ended or time.monotonic()
        found: dict[tuple[int, int], int] = {}
        for a in self.agents:
            for cell, s in a.knowledge.targets.items():
                found[cell] = min(found.get(cell, s), s)
        vehicles: list[dict[str, Any]] = []
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
                    distance_3d_m=round(a.distance, 1),
                    refused_moves=a.refused,
                    step_timeouts=a.timeouts,
                    sensor_reports=a.feed.reports,
                    error=a.error,
                    knowledge_sent=c.get("sent_packets", 0),
                    knowledge_received=c.get("received_packets", 0),
                    knowledge_rejected=c.get("rejected", 0),
                    knowledge_rejections=a.exchange.rejections(),
                    knowledge_withheld=c.get("withheld", 0),
                    mavlink_lost=self.lost_packets.get(a.spec.sysid, 0),
                )
            )
        rejections: Counter[str] = Counter()
        for v in vehicles:
            rejections.update(v["knowledge_rejections"])
        if self.bus is not None:
            rejections.update(self.bus.trust.rejected)
        links = [
            dict(
                connection=str(k),
                sent=v.stats.sent,
                received=v.stats.received,
                bad_data=v.stats.bad_data,
                console_bytes=v.stats.console_bytes,
                dropped_bytes=v.stats.dropped_bytes,
                unknown=v.stats.unknown,
                **link_signing(v),
            )
            for k, v in self.links.items()
        ]
        # who hovered where when the search ended (a vehicle's end action may have brought it home since)
        hovering = self.on_targets if self.ended else [a.here for a in self.agents if a.state is State.HOVER]
        out: dict[str, Any] = dict(
            mission=self.plan.spec.mission.name,
            policy=self.plan.policy.spec,
            outcome=self.outcome,
            targets_found=[
                dict(cell=list(c), lat=self.grid.cell_to_latlon(*c)[0], lon=self.grid.cell_to_latlon(*c)[1], step=s)
                for c, s in sorted(found.items())
            ],
            vehicles_on_targets=[list(c) for c in hovering],
            time_s=round(now - self.state.started, 2),
            search_time_s=round(self.state.search_seconds(), 2),
            steps=self.step,
            vehicles=vehicles,
            messages=dict(
                mavlink_sent=sum(v.stats.sent for v in self.links.values()),
                mavlink_received=sum(v.stats.received for v in self.links.values()),
                mavlink_lost=sum(self.lost_packets.values()),
                knowledge_sent=sum(v["knowledge_sent"] for v in vehicles),
                knowledge_received=sum(v["knowledge_received"] for v in vehicles),
                knowledge_rejected=sum(rejections.values()),
                knowledge_rejections=dict(sorted(rejections.items())),
            ),
            links=links,
            overhead_ms=self.overhead_ms(),
            recording_lost=dict(self.rec.lost),  # file -> why it stopped being written (swarmctl.mission.recorder)
            fault=self.state.fault,  # an unexpected error that stopped the mission (events "fault")
        )
        out.update(self.finish.summary(self.outcome, out["targets_found"]))
        if extra:
            out.update(extra)
        return out
