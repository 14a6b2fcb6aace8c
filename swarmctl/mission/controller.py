"""The controller: one agent per vehicle, flown through connect -> preflight -> takeoff -> search ->
hover on a target -> end action, in lock-step decision rounds on one asyncio loop.

Where each part lives: the agents' state machine in agent.py; connect, preflight, take-off and rejoin
in launch.py; the decision rounds in rounds.py; flying to a cell and sensing there in flight.py. This
module opens the agents, runs those, and ends the mission: every vehicle that is still in contact
gets the end action (land, rtl, or hover: vehicles hovering on a target hold there, the others
return home), and the recording gets the summary. Every task the controller starts is kept
(`spawn`) and finished before the mission returns.

Link loss: a vehicle whose heartbeats stop is marked lost and left to its own failsafe; the others
carry on and the guard keeps its last cell free. When it comes back it rejoins (launch.rejoin).
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
from swarmctl.geo.fence import fence_polygon
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mavlink.gcs import GcsForwarder
from swarmctl.mission import timeouts
from swarmctl.mission.agent import Agent, State
from swarmctl.mission.detector import SensorFeed, UdpSensorSource
from swarmctl.mission.finish import FinishLine
from swarmctl.mission.flight import cancel
from swarmctl.mission.launch import start
from swarmctl.mission.plan import MissionPlan
from swarmctl.mission.recorder import Recorder
from swarmctl.mission.rounds import search
from swarmctl.mission.sharing import link_outlet, make_bus, open_exchange
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
        view: Callable[[Controller], None] | None = None,
    ):
        self.plan = plan
        self.rec = recorder
        self.view = view
        self.grid = plan.grid
        self.guard = SafetyGuard(self.grid.blocked, plan.altitude)
        self.fence = fence_polygon(self.grid) if plan.spec.mission.fence else None  # (lat, lon) vertices
        self.policy = plan.policy
        self.agents: list[Agent] = []
        self.links: dict[str, Any] = {}  # connection -> MavlinkLink, shared by the vehicles on it
        self.connector: Any = None  # swarmctl.mavlink.connect.Connector, made by _open
        self.mission_error: InputError | None = None  # what stopped the mission: raised by run()
        self.sources: list[UdpSensorSource] = []
        self.bus = make_bus(plan)  # ground mode: the agents share in memory (None: onboard, the channel)
        gcs = plan.spec.mission.gcs
        self.gcs = GcsForwarder(gcs.host, gcs.port) if gcs is not None else None
        self.step = 0
        self.outcome: str | None = None
        self.started = time.monotonic()
        self.search_started: float | None = None
        self.ended: float | None = None
        self.on_targets: list[tuple[int, int]] = []  # the cells hovered on when the search ended
        self.finish = FinishLine(plan)  # the mission's finish line, its finds and coverage (mission.finish)
        self.policy.set_hold(self.finish.to_hold)  # the hover rule parks once that many targets are known
        self.decide_times: list[float] = []
        self.round_times: list[float] = []
        self.wait_times: list[float] = []  # per round: waiting for vehicles to arrive and for detectors
        self.cpu_times: list[float] = []  # per round: CPU time of the controller's loop thread
        self.process_cpu_times: list[float] = []  # per round: CPU time of the whole process (every thread)
        self._stop = asyncio.Event()
        self.takeoff_slots = asyncio.Semaphore(plan.spec.flight.takeoff_at_once)
        self.tasks: set[asyncio.Task] = set()  # every task started with spawn(), until it is done
        # MAVLink sequence gaps, kept for the mission's system ids only (bounded: not one entry per id heard)
        self._sysids = {v.sysid for v in plan.spec.vehicles}
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
            finish=self.finish.rule,
            expected_targets=self.finish.expected,
            on_find=self.finish.on_find,
            **self.plan.policy.recorded(),
        )
        try:
            await self._open()
            await self._start_all()
            if not self.stopping:
                await search(self)
        except asyncio.CancelledError:
            self.outcome = "interrupted"
            await asyncio.shield(self._finish_safely())
            raise
        except Exception:  # a bug: the vehicles in the air still get their end action before it is raised
            self.outcome = "failed"
            await self._finish_safely()
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
            first_link_id=None if plan.only is None else min(plan.only) % 256,  # onboard: the vehicle's index
        )
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
            self.agents.append(agent)

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

    async def _start_all(self) -> None:
        await asyncio.gather(*(start(self, a) for a in self.agents))

    async def until_stopped(self, coro: Any) -> Any:
        """Await coro unless stop() is called first (then coro is cancelled)."""
        task = asyncio.ensure_future(coro)
        stopper = asyncio.ensure_future(self._stop.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            await cancel(task)
            return None
        return task.result()

    async def pause(self, seconds: float) -> None:
        """Wait `seconds`, or less if the mission is stopped."""
        try:
            await asyncio.wait_for(self._stop.wait(), seconds)
        except TimeoutError:
            pass

    def enter(self, a: Agent, state: State, **extra: Any) -> None:
        """Move an agent to `state` (Agent.enter checks the transition) and record it."""
        if a.enter(state) or extra:
            self.rec.event("state", vehicle=a.name, sysid=a.spec.sysid, state=state, cell=a.cell, **extra)

    def spawn(self, coro: Any, name: str) -> asyncio.Task:
        """Start a task the controller keeps until it is done (cancelled and awaited at the end)."""
        task = asyncio.ensure_future(coro)
        task.set_name(name)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return task

    async def quietly(self, coro: Any) -> None:
        """Await a command whose failure is only worth a log line (e.g. the low-battery RTL)."""
        try:
            await coro
        except (TimeoutError, MavlinkError) as exc:
            log.warning("%s", exc)

    def ours(self, vehicle_index: int) -> bool:
        """The vehicle (its index in the mission) is flown by this process."""
        only = self.plan.only  # the agents are made for exactly these vehicles (all of them: None)
        return 0 <= vehicle_index < len(self.plan.spec.vehicles) and (only is None or vehicle_index in only)

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
        self.on_targets = [a.cell for a in self.agents if a.state is State.HOVER and a.cell is not None]
        try:
            self.rec.ending()  # what follows is written into the space the recording kept for it
            self.finish.close(self, self.outcome)
            for a in self.agents:
                if a.rejoin_task is not None:
                    a.rejoin_task.cancel()
            await self._settle_tasks()
            self.rec.event("end", outcome=self.outcome, step=self.step)
        finally:  # whatever failed above, every vehicle in the air gets its end action
            done = await asyncio.gather(*(self._end_action(a) for a in self.agents), return_exceptions=True)
            for a, result in zip(self.agents, done):
                if isinstance(result, Exception):  # after its command: only what was recorded of it
                    log.error("%s: after the end action: %s: %s", a.name, type(result).__name__, result)
        if self.view is not None:
            self.view(self)

    async def _settle_tasks(self) -> None:
        """Let the commands in flight (a low-battery RTL) finish, for a few seconds at most; cancel the
        rest (rejoins), and wait until every task is done."""
        pending = [t for t in self.tasks if not t.done()]
        if pending:
            _, late = await asyncio.wait(pending, timeout=5.0)
            for t in late:
                await cancel(t)

    async def _end_action(self, a: Agent) -> None:
        plan = self.plan
        if a.state in (State.FAILED, State.CONNECT, State.PREFLIGHT) and not a.vehicle.armed:
            a.end_state = a.state
            return
        silenced = a.vehicle.silenced
        if (a.state is State.LOST or a.vehicle.lost) and silenced is None:
            a.end_state = "lost (left to its failsafe)"
            self.rec.event("end_action", vehicle=a.name, action="none: link lost")
            return
        # a vehicle judged silent because a listener failed on its messages still hears us (its link is
        # up, so its GCS failsafe will not act): it is sent its end action all the same, unconfirmed
        if a.state is State.OVERRIDE:
            who = "pilot" if a.override_reason == "pilot" else f"taken over, {a.override_reason}"
            a.end_state = f"{who} ({a.vehicle.mode})"
            return
        action = plan.spec.mission.end_action
        if action == "hover" and a.state is not State.HOVER:
            action = "rtl"  # only vehicles on a target hold; the others come home
        if a.state is State.LOW_BATTERY:
            action = "rtl"
        a.end_action = action
        try:  # nothing the recording raises may keep the command from the vehicle
            self.rec.event("end_action", vehicle=a.name, action=action, cell=a.cell)
        except Exception as exc:
            log.error("%s: the end_action line was not recorded: %s: %s", a.name, type(exc).__name__, exc)
        try:
            if action == "land":
                await a.vehicle.land()
            elif action == "rtl":
                await a.vehicle.rtl()
            wait = timeouts.end(plan.spec.timing.end_timeout, a.vehicle, action, plan.altitude)
            if action in ("land", "rtl") and wait > 0:
                await a.vehicle.wait_landed(wait)
                a.end_state = "landed at home" if action == "rtl" else "landed"
            else:
                a.end_state = "hovering on target" if a.state is State.HOVER else "hovering"
        except (TimeoutError, MavlinkError) as exc:
            a.end_state = f"end action failed: {exc}"
            self.rec.event("end_action_failed", vehicle=a.name, error=str(exc))
        except Exception as exc:  # one vehicle's unexpected error must not cut the others' end actions short
            a.end_state = f"end action failed: unexpected {type(exc).__name__}: {exc}"
            log.error("%s: %s", a.name, a.end_state)
            self.rec.event("end_action_failed", vehicle=a.name, error=f"{type(exc).__name__}: {exc}")
        self.enter(a, State.ENDED, end_state=a.end_state)

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
        """Per decision round (ms): the policy, the CPU time of the controller's loop thread and of the
        whole process (the loop, stream links' reader threads, any worker threads), the whole round, and
        the controller's own part of it in wall time (the round minus the time spent waiting for
        vehicles to arrive and for detector reports)."""
        n = min(len(self.round_times), len(self.wait_times))
        if not n:
            return dict(rounds=0)
        rounds, waits = np.array(self.round_times[:n]), np.array(self.wait_times[:n])
        own = np.maximum(rounds - waits, 0.0)
        return dict(
            rounds=n,
            decide_mean=round(1000 * float(np.mean(self.decide_times)), 3),
            cpu_mean=round(1000 * float(np.mean(self.cpu_times)), 3),
            process_cpu_mean=round(1000 * float(np.mean(self.process_cpu_times)), 3),
            round_mean=round(1000 * float(rounds.mean()), 3),
            controller_mean=round(1000 * float(own.mean()), 3),
            controller_p95=round(1000 * float(np.percentile(own, 95)), 3),
        )

    def summary(self, extra: dict | None = None) -> dict:
        now = self.ended or time.monotonic()
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
                knowledge_rejected=sum(rejections.values()),
                knowledge_rejections=dict(sorted(rejections.items())),
            ),
            links=links,
            overhead_ms=self.overhead_ms(),
            recording_lost=dict(self.rec.lost),  # file -> why it stopped being written (swarmctl.mission.recorder)
        )
        out.update(self.finish.summary(self, self.outcome, out["targets_found"]))
        if extra:
            out.update(extra)
        return out
