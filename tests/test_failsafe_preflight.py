"""Failsafes checked before take-off (swarmctl/mission/failsafes.py): a mock vehicle whose GCS failsafe is
off is refused with the parameter, its value and the fix before anything takes off; allow_no_failsafe =
true flies it with a warning; `swarmctl fly` says what each vehicle does on link loss."""

from __future__ import annotations

import asyncio
import io
import json
from collections import Counter

import pytest

from swarmctl.cli import main
from swarmctl.errors import InputError
from swarmctl.mavlink.autopilots.descriptions import ARDUPILOT, PX4
from swarmctl.mavlink.errors import CommandTimeout
from swarmctl.mission.failsafes import FAILSAFE_READS, Failsafe, read, refusal
from swarmctl.sim.swarm import SimSwarm
from tests.mission_support import fly, small_grid, small_mission


def events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


def notes(folder) -> list[str]:
    return [e["text"] for e in events(folder) if e["event"] == "preflight"]


@pytest.mark.parametrize(
    ("autopilot", "off", "parameter", "fix"),
    [
        ("ardupilot", {"FS_GCS_ENABLE": 0}, "FS_GCS_ENABLE", "set FS_GCS_ENABLE to 1 (RTL)"),
        ("px4", {"NAV_DLL_ACT": 0}, "NAV_DLL_ACT", "set NAV_DLL_ACT to 2 (return)"),
    ],
)
def test_a_vehicle_with_its_gcs_failsafe_off_is_refused_before_anything_takes_off(
    tmp_path, autopilot, off, parameter, fix
):
    grid = small_grid()
    # two vehicles: the one with a failsafe must not take off while the other is refused
    with SimSwarm(grid, uavs=2, seed=1, speedup=20.0, autopilots=[autopilot] * 2) as swarm:
        swarm.mocks[1].params.update({k: float(v) for k, v in off.items()})
        plan = swarm.plan("frontier", end_action="land", time_limit=30.0)
        with pytest.raises(InputError) as caught:
            fly(plan, tmp_path, timeout=60.0)
        took_off = [m.armed or m.rel_alt > 0.1 for m in swarm.mocks]
    line = str(caught.value)
    assert "\n" not in line
    assert line.startswith("uav2: ") and f"{parameter} is 0" in line and fix in line
    assert "allow_no_failsafe = true" in line
    assert took_off == [False, False]


def test_allow_no_failsafe_flies_it_with_a_warning(tmp_path, caplog):
    grid = small_grid()
    with SimSwarm(grid, uavs=1, seed=1, speedup=20.0, params={"FS_GCS_ENABLE": 0.0}) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=8.0, allow_no_failsafe=True)
        with caplog.at_level("WARNING", logger="swarmctl.mission.failsafes"):
            controller, outcome = fly(plan, tmp_path, timeout=90.0)
    assert outcome in ("complete", "time limit"), outcome
    assert controller.agents[0].state.value == "ended", controller.agents[0].error
    warned = [r.getMessage() for r in caplog.records if "without a GCS failsafe" in r.getMessage()]
    assert warned and "uav1" in warned[0] and "FS_GCS_ENABLE 0" in warned[0]
    said = notes(tmp_path)
    assert any(t.startswith("on link loss: nothing (GCS failsafe off) (FS_GCS_ENABLE 0)") for t in said), said


def test_a_default_mock_reports_what_it_does_on_link_loss_battery_and_fence(tmp_path):
    grid = small_grid()
    with SimSwarm(grid, uavs=2, seed=2, speedup=20.0, autopilots=["ardupilot", "px4"]) as swarm:
        plan = swarm.plan("frontier", end_action="land", time_limit=5.0, fence=True)
        controller, outcome = fly(plan, tmp_path, timeout=90.0)
    said = notes(tmp_path)
    assert (
        "on link loss: RTL (FS_GCS_ENABLE 1); on low battery: nothing (warning only) (BATT_FS_LOW_ACT 0); "
        "on fence breach: RTL, else land (FENCE_ACTION 1)" in said
    ), said
    assert (
        "on link loss: return (NAV_DLL_ACT 2); on low battery: return at critical level, land at emergency "
        "level (COM_LOW_BAT_ACT 3); "
        "on fence breach: hold (GF_ACTION 2)" in said
    ), said
    assert all(a.failsafes is not None for a in controller.agents)


def test_fly_says_what_each_vehicle_does_on_link_loss_before_it_asks(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert main(["fly", str(small_mission(tmp_path))]) == 1
    out = capsys.readouterr().out
    assert "link loss: each vehicle's own GCS failsafe decides" in out
    assert "refused before anything takes off (allow_no_failsafe = false)" in out
    assert "vehicle a on link loss: unknown until connected" in out


def test_the_refusal_names_an_unreadable_parameter_and_the_fix():
    line = refusal("alpha", ARDUPILOT, Failsafe("FS_GCS_ENABLE", None, "unknown", True, "no answer"))
    assert line.startswith("alpha: FS_GCS_ENABLE could not be read (no answer)")
    assert "set FS_GCS_ENABLE to 1 (RTL) or 5 (land)" in line and "allow_no_failsafe = true" in line
    assert PX4.failsafe_is_off("GF_ACTION", 1) and not PX4.failsafe_is_off("NAV_DLL_ACT", 3)
    assert ARDUPILOT.failsafe_action("FS_GCS_ENABLE", 9.0) == "FS_GCS_ENABLE 9 (unknown to swarmctl)"

    class Silent:
        autopilot_info = PX4

        async def read_parameter(self, name):
            from swarmctl.mavlink.errors import MavlinkError

            raise MavlinkError(f"no {name}")

    found = asyncio.run(read(Silent(), fence=False))
    assert set(found) == {"link", "battery"} and found["link"].off and found["link"].value is None


class UnansweredVehicle:
    """A vehicle each of whose parameters goes unanswered the first `silent` reads, then is answered 1."""

    name, autopilot_info = "alpha", ARDUPILOT

    def __init__(self, silent: int):
        self.silent, self.reads = silent, Counter[str]()

    async def read_parameter(self, name: str) -> float:
        self.reads[name] += 1
        if self.reads[name] <= self.silent:
            raise CommandTimeout(f"reading parameter {name}", self.name, 6, 1.0)
        return 1.0


@pytest.mark.parametrize("silent", [FAILSAFE_READS - 1, FAILSAFE_READS])
def test_a_failsafe_parameter_left_unanswered_is_read_again(silent):
    """Silence on a lossy link is not a refusal: it is read again, FAILSAFE_READS times in all."""
    vehicle = UnansweredVehicle(silent)
    link = asyncio.run(read(vehicle, fence=False))["link"]
    assert vehicle.reads["FS_GCS_ENABLE"] == min(silent + 1, FAILSAFE_READS)
    if silent < FAILSAFE_READS:
        assert link.value == 1.0 and not link.off
    else:
        assert link.value is None and link.off and "after 6 attempts" in link.error
