"""Real ArduCopter and PX4 SITL answer plain pymavlink, and the harness always cleans up after them.

Skipped with the reason when the binaries are absent (ARDUPILOT_SITL, PX4_SITL; see
tests/sitl_support.py and tests/px4_support.py).
"""

from __future__ import annotations

import time

import pytest
from pymavlink import mavutil

from tests.px4_support import AUTOPILOT_PX4, free_px4_instances, instance_busy, lock_file, px4_sitl, socket_file
from tests.sitl_support import (
    CHICAGO_HOME,
    arducopter_sitl,
    mavlink_client,
    read_param,
    request_message_interval,
    tcp_listening,
    wait_message,
)

pytestmark = pytest.mark.sitl

MAV = mavutil.mavlink


def test_arducopter_sends_heartbeats_and_streams_position_once_asked():
    with arducopter_sitl(1, params={"BATT_CAPACITY": 33000}) as [copter], mavlink_client(copter.connection) as conn:
        hb = wait_message(conn, "HEARTBEAT", 30, sysid=copter.sysid)
        assert (hb.autopilot, hb.type) == (MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, MAV.MAV_TYPE_QUADROTOR)
        assert read_param(conn, copter.sysid, "BATT_CAPACITY") == 33000  # the harness's defaults on copter.parm
        assert read_param(conn, copter.sysid, "MAV_SYSID") == copter.sysid == copter.instance + 1
        # a request sent while the vehicle boots can be lost: repeat it until the stream starts
        ask = lambda: request_message_interval(conn, copter.sysid, MAV.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 5.0)
        wait_message(conn, "GLOBAL_POSITION_INT", 30, sysid=copter.sysid, every=ask)
        start, count = time.monotonic(), 0
        while time.monotonic() - start < 2.0:
            wait_message(conn, "GLOBAL_POSITION_INT", 2.0, sysid=copter.sysid)
            count += 1
        assert count >= 4, f"{count} GLOBAL_POSITION_INT in 2 s at a requested 5 Hz"


def test_px4_instances_side_by_side_send_their_heartbeats_on_their_api_links():
    with px4_sitl(2) as vehicles:
        for px4 in vehicles:
            assert instance_busy(px4.instance), f"instance {px4.instance} runs but reads as free"
            assert px4.instance not in free_px4_instances(1)
            with mavlink_client(px4.connection) as conn:
                hb = wait_message(conn, "HEARTBEAT", 30)
                assert (hb.autopilot, hb.type) == (AUTOPILOT_PX4, MAV.MAV_TYPE_QUADROTOR)
                assert hb.get_srcSystem() == px4.sysid == px4.instance + 1
    for px4 in vehicles:
        assert not lock_file(px4.instance).exists() and not socket_file(px4.instance).exists()


def test_instances_are_stopped_and_removed_when_the_test_fails():
    with pytest.raises(RuntimeError, match="the test failed"):
        with arducopter_sitl(1, homes=[CHICAGO_HOME]) as [copter], px4_sitl(1) as [px4]:
            procs = [copter.proc, px4.proc]
            raise RuntimeError("the test failed")
    for proc in procs:
        assert proc.process.returncode is not None, f"{proc.name} still running"
        assert not proc.folder.exists(), f"{proc.name}'s folder {proc.folder} left behind"
    assert not tcp_listening(copter.port)
    assert not lock_file(px4.instance).exists() and not socket_file(px4.instance).exists()
