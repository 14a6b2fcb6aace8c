"""Mission files (TOML), validated: every problem is one line naming the key and the fix.

    [mission]
    name = "chicago-loop"
    id = 7                      # mission id carried by knowledge messages (0..65535)
    grid = "chicago-loop/grid.npz"   # a grid from `swarmctl plan`, or:
    # area = "area.geojson"; buildings = "buildings.geojson"; cell_size = 10
    altitude = 40.0             # metres above home
    policy = "ddql:../models/cluster-2uav.pt:tau=0.1"
    step_period = 1.0           # seconds between decisions
    step_timeout = 30.0         # seconds to reach a cell before the step is given up
    time_limit = 900.0          # seconds for the whole search
    end_action = "rtl"          # land | rtl | hover
    signing_key = "swarm.key"   # optional, 32-byte MAVLink 2 signing key
    gcs = "udpout:127.0.0.1:14550"   # optional: forward the vehicles' MAVLink to a ground station
    fence = true                # optional (default false): upload the area's boundary to each vehicle as its geofence

    [knowledge]
    channel = "udpout:127.0.0.1:14600"   # where the agents exchange TUNNEL messages

    [[vehicles]]
    name = "alpha"
    connection = "udpin:0.0.0.0:14551"
    sysid = 1
    autopilot = "ardupilot"     # ardupilot | px4
    # detector = "udp:127.0.0.1:14650"   # optional: a local socket its detector reports to (PX4 needs it)

Relative paths are relative to the mission file.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from swarmctl.errors import InputError

END_ACTIONS = ("land", "rtl", "hover")
AUTOPILOTS = ("ardupilot", "px4")
OBSERVATION_WINDOW = 20  # F: the controller observes 20 x 20 windows, like the simulator

_MISSION_KEYS = {
    "name",
    "id",
    "grid",
    "area",
    "buildings",
    "cell_size",
    "altitude",
    "policy",
    "step_period",
    "step_timeout",
    "time_limit",
    "end_action",
    "signing_key",
    "gcs",
    "fence",
}
_KNOWLEDGE_KEYS = {"channel", "digest_every"}
_VEHICLE_KEYS = {"name", "connection", "sysid", "autopilot", "detector"}
_TOP_KEYS = {"mission", "knowledge", "vehicles"}


@dataclass(frozen=True)
class VehicleSpec:
    name: str
    connection: str
    sysid: int
    autopilot: str = "ardupilot"
    detector: str | None = None  # udp:HOST:PORT where its detector sends reports (else its MAVLink link)


@dataclass
class MissionConfig:
    path: Path
    name: str
    mission_id: int
    vehicles: list[VehicleSpec]
    policy: str
    grid: Path | None = None
    area: Path | None = None
    buildings: Path | None = None
    cell_size: float = 10.0
    altitude: float = 40.0
    step_period: float = 1.0
    step_timeout: float = 30.0
    time_limit: float = 900.0
    end_action: str = "rtl"
    signing_key: Path | None = None
    knowledge_channel: str | None = None
    digest_every: int = 5
    gcs: str | None = None
    fence: bool = False  # upload the area's boundary to every vehicle as its inclusion geofence


def _fail(path: Path, key: str, problem: str, fix: str) -> InputError:
    return InputError(f"{path}: {key} {problem}; {fix}")


def _unknown(path: Path, table: dict, allowed: set, where: str) -> None:
    for key in table:
        if key not in allowed:
            raise _fail(path, f"{where}{key}", "is not a known key", f"use one of {', '.join(sorted(allowed))}")


def _number(path, table, key, where, default, minimum=None, integer=False):
    value = table.get(key, default)
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise _fail(
            path,
            f"{where}{key}",
            f"must be {'an integer' if integer else 'a number'}, not {value!r}",
            f"write for example {key} = {default}",
        )
    if minimum is not None and value < minimum:
        raise _fail(path, f"{where}{key}", f"= {value} is below {minimum}", f"use a value >= {minimum}")
    return value


def _file(path: Path, table: dict, key: str, where: str) -> Path | None:
    value = table.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise _fail(path, f"{where}{key}", "must be a file path string", f'write {key} = "path/to/file"')
    resolved = (path.parent / value).resolve()
    if not resolved.is_file():
        raise _fail(
            path,
            f"{where}{key}",
            f"names {value!r}, which does not exist",
            "fix the path (relative to the mission file)",
        )
    return resolved


def load_mission(path: str | Path) -> MissionConfig:
    """Read and validate a mission file; InputError names the key and the fix."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such mission file")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc}); fix the syntax at that line") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file; a mission file is TOML") from None
    _unknown(path, data, _TOP_KEYS, "")
    mission = data.get("mission")
    if not isinstance(mission, dict):
        raise _fail(path, "[mission]", "is missing", "add a [mission] table with at least policy and grid or area")
    _unknown(path, mission, _MISSION_KEYS, "mission.")
    where = "mission."

    grid = _file(path, mission, "grid", where)
    area = _file(path, mission, "area", where)
    buildings = _file(path, mission, "buildings", where)
    if grid is None and area is None:
        raise _fail(path, "mission.grid", "is missing", "give grid (from `swarmctl plan`) or area")
    if grid is not None and (area is not None or buildings is not None):
        raise _fail(
            path, "mission.grid", "is given together with area/buildings", "give either grid or area (+ buildings)"
        )
    end_action = mission.get("end_action", "rtl")
    if end_action not in END_ACTIONS:
        raise _fail(path, "mission.end_action", f"= {end_action!r} is unknown", f"use one of {', '.join(END_ACTIONS)}")
    policy = mission.get("policy")
    if not isinstance(policy, str) or not policy:
        raise _fail(
            path, "mission.policy", "is missing", 'write for example policy = "ddql:models/cluster-2uav.pt" or "la:4"'
        )
    if policy.startswith(("ddql:", "ddql-greedy:")):
        from swarmctl.policy.checkpoint import load_checkpoint
        from swarmctl.policy.ddql import split_options
        from swarmctl.policy.registry import make_policy

        kind, _, rest = policy.partition(":")
        model, options = split_options(rest)
        model_path = (path.parent / model).resolve()
        if not model_path.is_file():
            raise _fail(
                path,
                "mission.policy",
                f"names the model {model!r}, which does not exist",
                "fix the path (relative to the mission file)",
            )
        policy = f"{kind}:{model_path}{options}"
        try:
            load_checkpoint(model_path, window=OBSERVATION_WINDOW)
            make_policy(policy)  # the options
        except InputError as exc:
            raise InputError(f"{path}: mission.policy: {exc}") from None
    else:
        from swarmctl.policy.registry import make_policy

        try:
            make_policy(policy)
        except InputError as exc:
            raise InputError(f"{path}: mission.policy: {exc}") from None
    mission_id = _number(path, mission, "id", where, 1, 0, integer=True)
    if mission_id > 65535:
        raise _fail(path, "mission.id", f"= {mission_id} is too large", "use 0..65535")

    knowledge = data.get("knowledge", {})
    if not isinstance(knowledge, dict):
        raise _fail(path, "[knowledge]", "must be a table", 'write [knowledge] channel = "udpout:127.0.0.1:14600"')
    _unknown(path, knowledge, _KNOWLEDGE_KEYS, "knowledge.")

    vehicles_raw = data.get("vehicles")
    if not isinstance(vehicles_raw, list) or not vehicles_raw:
        raise _fail(
            path, "[[vehicles]]", "is missing", "add one [[vehicles]] table per vehicle (name, connection, sysid)"
        )
    vehicles: list[VehicleSpec] = []
    for i, v in enumerate(vehicles_raw):
        w = f"vehicles[{i}]."
        if not isinstance(v, dict):
            raise _fail(path, f"vehicles[{i}]", "must be a table", "write [[vehicles]] blocks")
        _unknown(path, v, _VEHICLE_KEYS, w)
        name = v.get("name")
        if not isinstance(name, str) or not name:
            raise _fail(path, f"{w}name", "is missing", 'give every vehicle a name = "..."')
        connection = v.get("connection")
        if not isinstance(connection, str) or not connection:
            raise _fail(path, f"{w}connection", "is missing", 'write for example connection = "udpin:0.0.0.0:14551"')
        _check_connection(path, f"{w}connection", connection)
        if "sysid" not in v:
            raise _fail(path, f"{w}sysid", "is missing", "give the vehicle's MAVLink system id (SYSID_THISMAV), 1..250")
        sysid = _number(path, v, "sysid", w, 1, 1, integer=True)
        if sysid > 250:
            raise _fail(path, f"{w}sysid", f"= {sysid} is out of range", "use 1..250 (SYSID_THISMAV)")
        autopilot = v.get("autopilot", "ardupilot")
        if autopilot not in AUTOPILOTS:
            raise _fail(path, f"{w}autopilot", f"= {autopilot!r} is unknown", f"use one of {', '.join(AUTOPILOTS)}")
        detector = v.get("detector")
        if detector is not None:
            host, _, port = str(detector).removeprefix("udp:").rpartition(":")
            if (
                not isinstance(detector, str)
                or not detector.startswith("udp:")
                or not host
                or not port.isdigit()
                or not 0 < int(port) < 65536
            ):
                raise _fail(
                    path,
                    f"{w}detector",
                    f"= {detector!r} is not a UDP address",
                    'write for example detector = "udp:127.0.0.1:14650"',
                )
        for other in vehicles:
            if other.name == name:
                raise _fail(path, f"{w}name", f"{name!r} is listed twice", "give every vehicle its own name")
            if other.sysid == sysid and other.connection == connection:
                raise _fail(
                    path,
                    f"{w}sysid",
                    f"{sysid} clashes with {other.name!r} on the same link",
                    "give every vehicle its own system id (SYSID_THISMAV)",
                )
            if other.sysid == sysid:
                raise _fail(
                    path,
                    f"{w}sysid",
                    f"{sysid} is also {other.name!r}'s system id",
                    "system ids must be unique in a swarm (SYSID_THISMAV)",
                )
        vehicles.append(VehicleSpec(name, connection, sysid, autopilot, detector))

    return MissionConfig(
        path=path.resolve(),
        name=str(mission.get("name", path.stem)),
        mission_id=mission_id,
        vehicles=vehicles,
        policy=policy,
        grid=grid,
        area=area,
        buildings=buildings,
        cell_size=_number(path, mission, "cell_size", where, 10.0, 0.1),
        altitude=_number(path, mission, "altitude", where, 40.0, 2.0),
        step_period=_number(path, mission, "step_period", where, 1.0, 0.0),
        step_timeout=_number(path, mission, "step_timeout", where, 30.0, 0.1),
        time_limit=_number(path, mission, "time_limit", where, 900.0, 1.0),
        end_action=end_action,
        signing_key=_file(path, mission, "signing_key", where),
        knowledge_channel=knowledge.get("channel"),
        digest_every=_number(path, knowledge, "digest_every", "knowledge.", 5, 1, integer=True),
        gcs=_gcs(path, mission),
        fence=_flag(
            path,
            mission,
            "fence",
            where,
            False,
            "to upload the search area's boundary to every vehicle as its geofence",
        ),
    )


def _flag(path: Path, table: dict, key: str, where: str, default: bool, meaning: str) -> bool:
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise _fail(
            path,
            f"{where}{key}",
            f"must be true or false, not {value!r}",
            f"write {key} = true {meaning}, or leave it out",
        )
    return value


def _gcs(path: Path, mission: dict) -> str | None:
    value = mission.get("gcs")
    if value is None:
        return None
    if not isinstance(value, str) or not value.startswith("udpout:"):
        raise _fail(
            path,
            "mission.gcs",
            f"= {value!r} is not a UDP address to send to",
            'write for example gcs = "udpout:127.0.0.1:14550" (QGroundControl listens there)',
        )
    _check_connection(path, "mission.gcs", value)
    return value


def _check_connection(path: Path, key: str, connection: str) -> None:
    try:
        from swarmctl.mavlink.codec import parse_connection
    except ImportError:  # pragma: no cover - the MAVLink package ships with the controller
        return
    try:
        parse_connection(connection, field=key)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
