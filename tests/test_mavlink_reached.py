"""`Vehicle.reached` keeps its answer for the same position report and target: a new report, a new
target or another tolerance is measured again, with the figures of a fresh measurement."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.mavlink.autopilots.ardupilot import ArduPilotVehicle
from swarmctl.mavlink.codec import distance_m
from swarmctl.mavlink.network import MavlinkLink, Peer
from swarmctl.mavlink.vehicle import Target


def position_report(lat_e7: int, lon_e7: int, rel_alt_mm: int):
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return mav.global_position_int_encode(0, lat_e7, lon_e7, 180000 + rel_alt_mm, rel_alt_mm, 0, 0, 0, 0)


def test_reached_follows_new_reports_targets_and_tolerances():
    link = MavlinkLink("udpin:127.0.0.1:0")
    link.peers[1] = peer = Peer(sysid=1)
    v = ArduPilotVehicle(link, 1)
    v.target = Target(41.88, -87.63, 40.0)

    def expected(tolerance: float) -> bool:
        pos, tgt = v.position, v.target
        horiz = distance_m(pos.lat, pos.lon, tgt.lat, tgt.lon)
        return (horiz**2 + (pos.rel_alt - tgt.rel_alt) ** 2) ** 0.5 <= tolerance

    answers = []
    for lat_e7, alt_mm, target_alt, tolerance in [
        (418800000, 40000, 40.0, 0.5),  # on the target
        (418800000, 40000, 40.0, 0.5),  # the same report again
        (418800000, 40000, 41.0, 0.5),  # a new target 1 m higher
        (418800000, 40000, 41.0, 1.5),  # a wider tolerance
        (418800100, 41000, 41.0, 0.5),  # a new report about 1.1 m north
        (418800000, 41000, 41.0, 0.5),  # and back
    ]:
        if v.target.rel_alt != target_alt:
            v.target = Target(41.88, -87.63, target_alt)
        last = peer.messages.get("GLOBAL_POSITION_INT")
        if last is None or (last.lat, last.relative_alt) != (lat_e7, alt_mm):  # else the same report object
            peer.messages["GLOBAL_POSITION_INT"] = position_report(lat_e7, -876300000, alt_mm)
        answers.append(v.reached(tolerance))
        assert answers[-1] == expected(tolerance)
    assert answers == [True, True, False, True, False, True]
