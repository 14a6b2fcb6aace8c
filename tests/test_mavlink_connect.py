"""The autopilot read from the vehicle: the connector picks the driver from the HEARTBEAT (or MAVSDK's
autopilot type), a mission key that disagrees stops the mission, and missions fly mock ArduPilots and
PX4s with no key at all."""

from __future__ import annotations

import asyncio
import json
import socket

import pytest
from pymavlink.dialects.v20 import ardupilotmega as MAV

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.autopilots.px4 import PX4Vehicle
from swarmctl.mavlink.connect import AutopilotMismatch, Connector
from swarmctl.mavlink.errors import MavlinkError
from swarmctl.mission.controller import Controller
from swarmctl.mission.recorder import Recorder
from swarmctl.sim.swarm import SimSwarm, free_udp_port
from tests.mavlink_support import mock_vehicles, our_threads, run
from tests.mission_support import fly, small_grid, wait_for


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    assert our_threads() == []


async def close_all(vehicles, links) -> None:
    for v in vehicles:
        await v.close()
    for link in links.values():
        await link.close()


def test_without_a_key_the_heartbeat_picks_the_driver_and_a_px4_gets_its_connection():
    px4_port = free_udp_port()

    async def scenario():
        links: dict = {}
        opened: list = []
        connector = Connector(links, on_open=opened.append)
        with mock_vehicles(
            dict(sysid=1, connect="udpin:127.0.0.1:0"),
            dict(sysid=2, connect=f"udpout:127.0.0.1:{px4_port}", autopilot="px4"),
        ) as (copter, _px4):
            connections = [f"udpout:127.0.0.1:{copter.local_port}", f"udpin:127.0.0.1:{px4_port}"]
            for c in connections:
                connector.expect(c)
            vehicles = await asyncio.gather(
                connector.connect(connections[0], 1, name="copter", timeout=10),
                connector.connect(connections[1], 2, name="px4", timeout=10),
            )
            try:
                await asyncio.gather(*(v.wait_ready(10) for v in vehicles))
                await wait_for(lambda: all(v.mode != "UNKNOWN" for v in vehicles), 5, "the mode reports")
                modes = [v.mode for v in vehicles]
                return vehicles, list(links), len(opened), modes
            finally:
                await close_all(vehicles, links)

    vehicles, links, opened, modes = run(scenario())
    assert [type(v) for v in vehicles] == [ArduPilotVehicle, PX4Vehicle]
    assert [v.autopilot for v in vehicles] == ["ardupilot", "px4"] and vehicles[1].sysid == 2
    assert opened == 2 and len(links) == 1  # the PX4's link was opened, read and handed to MAVSDK
    assert modes == ["GUIDED", "HOLD"]  # ArduPilot's preflight switches to GUIDED first; PX4 boots in HOLD


def test_a_key_that_disagrees_with_the_heartbeat_or_with_mavsdk_is_refused_with_the_fix():
    px4_port, copter_port = free_udp_port(), free_udp_port()

    async def scenario():
        links: dict = {}
        connector = Connector(links, source="m.toml")
        errors = []
        with mock_vehicles(
            dict(sysid=3, connect=f"udpout:127.0.0.1:{px4_port}", autopilot="px4"),
            dict(sysid=4, connect=f"udpout:127.0.0.1:{copter_port}"),
        ):
            for port, sysid, key in ((px4_port, 3, "ardupilot"), (copter_port, 4, "px4")):
                with pytest.raises(AutopilotMismatch) as err:
                    await connector.connect(f"udpin:127.0.0.1:{port}", sysid, name=f"uav{sysid}", autopilot=key)
                errors.append(str(err.value))
            await close_all([], links)
        return errors

    px4_said, copter_said = run(scenario())
    assert px4_said == (
        f"m.toml: uav3 (system id 3 on udpin:127.0.0.1:{px4_port}) reports a PX4 autopilot, but "
        'autopilot = "ardupilot" is set for it; write autopilot = "px4" for it, or leave the key out to fly what '
        "the vehicle reports"
    )
    assert copter_said.startswith(f"m.toml: uav4 (system id 4 on udpin:127.0.0.1:{copter_port}) reports a ")
    assert 'ArduPilot autopilot, but autopilot = "px4" is set for it; write autopilot = "ardupilot"' in copter_said


def test_a_px4_sharing_its_connection_is_refused_and_the_copter_beside_it_flies():
    async def scenario():
        links: dict = {}
        connector = Connector(links, source="m.toml")
        port = free_udp_port()
        connection = f"udpin:127.0.0.1:{port}"
        connector.expect(connection)
        connector.expect(connection)
        with mock_vehicles(
            dict(sysid=5, connect=f"udpout:127.0.0.1:{port}", autopilot="px4"),
            dict(sysid=6, connect=f"udpout:127.0.0.1:{port}"),
        ):
            with pytest.raises(AutopilotMismatch) as err:
                await connector.connect(connection, 5, name="uav5")
            copter = await connector.connect(connection, 6, name="uav6", autopilot="ardupilot")
            try:
                await copter.wait_ready(10)
                return str(err.value), type(copter), list(links)
            finally:
                await close_all([copter], links)

    error, kind, links = run(scenario())
    assert error.startswith("m.toml: uav5 (system id 5) reports a PX4 autopilot, which swarmctl flies on a ")
    assert error.endswith("carries 2 vehicles; give uav5 its own connection (e.g. its own UDP port)")
    assert kind is ArduPilotVehicle and len(links) == 1


def test_a_firmware_swarmctl_does_not_fly_fails_that_vehicle_or_contradicts_its_key():
    async def scenario():
        links: dict = {}
        connector = Connector(links, source="m.toml")
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        mav = MAV.MAVLink(None, srcSystem=7, srcComponent=1)
        outcomes = []
        port = free_udp_port()

        async def beat():
            hb = mav.heartbeat_encode(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_GENERIC, 0, 0, MAV.MAV_STATE_STANDBY)
            while True:
                sender.sendto(hb.pack(mav), ("127.0.0.1", port))
                await asyncio.sleep(0.2)

        beating = asyncio.create_task(beat())
        try:
            for key in (None, "ardupilot"):
                try:
                    await connector.connect(f"udpin:127.0.0.1:{port}", 7, name="uav7", autopilot=key, timeout=5)
                except MavlinkError as exc:
                    outcomes.append(("MavlinkError", str(exc)))
                except AutopilotMismatch as exc:
                    outcomes.append(("AutopilotMismatch", str(exc)))
        finally:
            beating.cancel()
            sender.close()
            await close_all([], links)
        return outcomes

    (kind1, said1), (kind2, said2) = run(scenario())
    assert kind1 == "MavlinkError" and "reports MAV_AUTOPILOT 0, which swarmctl does not fly" in said1
    assert "it flies ArduPilot (3), PX4 (12)" in said1
    assert kind2 == "AutopilotMismatch" and said2.endswith("is set for it; check its connection and system id")


# --- missions -----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_mission_without_autopilot_keys_flies_an_ardupilot_and_a_px4_identified_by_their_heartbeats(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=1, speedup=30.0, autopilots=["ardupilot", "px4"]) as swarm:
        swarm.specs = [v.model_copy(update={"autopilot": None}) for v in swarm.specs]
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0)
        controller, outcome = fly(plan, tmp_path)
        hidden = {tuple(t) for t in swarm.targets.tolist()}
    assert outcome == "complete"
    assert [type(a.vehicle) for a in controller.agents] == [ArduPilotVehicle, PX4Vehicle]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [v["autopilot"] for v in summary["vehicles"]] == ["ardupilot", "px4"]  # what the vehicles said
    assert {tuple(v["cell"]) for v in summary["vehicles"]} <= hidden
    assert [link["connection"] for link in summary["links"]] == [str(plan.spec.vehicles[0].connection)]  # PX4's went


@pytest.mark.slow
def test_a_key_the_vehicle_contradicts_stops_the_mission_before_the_others_take_off(tmp_path):
    # every vehicle's preflight (its failsafes read) ends before any takes off: the PX4 silent for 6 s
    # holds the copter on the ground, and the contradiction found then keeps it there
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=2, speedup=30.0, autopilots=["ardupilot", "px4"]) as swarm:
        swarm.specs[1] = swarm.specs[1].model_copy(update={"autopilot": "ardupilot"})  # it is a PX4
        plan = swarm.plan("frontier", end_action="hover", time_limit=120.0)
        copter, px4 = swarm.mocks
        px4.drop_heartbeats(6.0)  # silent while the copter would take off
        rec = Recorder(tmp_path)
        controller = Controller(plan, rec)
        highest = []

        async def main():
            watch = asyncio.ensure_future(wait_for(lambda: copter.rel_alt > 30.0, 30, "the copter to climb"))
            try:
                await controller.run()
            finally:
                highest.append(watch.done() and watch.exception() is None)
                watch.cancel()

        try:
            with pytest.raises(AutopilotMismatch) as err:
                asyncio.run(asyncio.wait_for(main(), 90))
        finally:
            rec.close()
        landed = not copter.armed and copter.rel_alt == 0.0
    message = str(err.value)
    assert message.startswith(f"the mission: uav2 (system id 2 on {plan.spec.vehicles[1].connection}) reports a PX4")
    assert "\n" not in message and 'write autopilot = "px4"' in message
    assert controller.outcome == "failed" and highest == [False]  # the copter never climbed
    first, second = controller.agents
    assert second.state == "failed" and second.error == message and second.vehicle.autopilot is None
    assert first.end_action is None and landed  # it never armed: nothing to bring home
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert {"event": "end", "outcome": "failed"}.items() <= next(e for e in events if e["event"] == "end").items()
