"""The mission spec: every setting of a mission, validated once, with its default in one place.

A mission file is TOML with the tables below (the keys, types, defaults and ranges are listed in
docs/mission.md, generated from this module: `python -m swarmctl.mission.spec --write docs/mission.md`):

    [mission]
    name = "chicago-loop"
    id = 7                          # mission id carried by knowledge messages (0..65535)
    grid = "grid.npz"               # a grid from `swarmctl plan`, or: area = "area.geojson" (+ buildings)
    policy = "ddql:../../models/obstacles-3uav.pt:straggler=frontier"
    end_action = "rtl"              # land | rtl | hover

    [timing]                        # step_period, step_timeout, time_limit and the waits of each stage
    [flight]                        # take-off spacing, reach tolerance, telemetry rate
    [battery]                       # the charge needed to start and the one that sends a vehicle home
    [knowledge]                     # the knowledge channel and its digests

    [[vehicles]]
    name = "alpha"
    connection = "udpin:0.0.0.0:14551"
    sysid = 1

Every number is finite and range-checked, types are strict (no true for a number, no "40" for 40),
unknown keys are refused with the known ones, and every problem is one InputError line: the file,
the key, the value, the rule and the fix. Relative paths are relative to the mission file.
Connections are parsed here, once, into `swarmctl.mavlink.codec.Endpoint`.

The file's altitude, cell size and sensor footprint may be left out; the plan (swarmctl.mission.plan)
fills them in from the grid and the policy, once, and checks them against both.
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from swarmctl.errors import InputError
from swarmctl.geo.defaults import DEFAULT_ALTITUDE, DEFAULT_CELL
from swarmctl.mavlink.autopilots import AutopilotName
from swarmctl.mavlink.codec import Endpoint, parse_connection
from swarmctl.mission.spec_text import SpecError, bounds, explain, markdown_table, replace_between, table_of_key
from swarmctl.world.config import FINISHES  # when the search is complete (swarmctl.mission.finish)

MAX_BYTES = 1_000_000  # a mission file is a few kB; anything this large is not one
EndAction = Literal["land", "rtl", "hover"]
END_ACTIONS: tuple[str, ...] = get_args(EndAction)
OnFind = Literal["hold", "mark"]  # what a vehicle does at a target it finds
ON_FIND: tuple[str, ...] = get_args(OnFind)
MAX_EXPECTED_TARGETS = 1 << 15  # a target a cell at most, and no grid a mission flies has more cells
PUSH_UP_TO = 12  # knowledge push is on for swarms of up to this many vehicles (see [knowledge] push)
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"  # names become parts of recording folder names
NAME_SPAN = "letters, digits, . _ - (up to 64)"
# The demo's settings over the defaults (and over a mission file's, with `swarmctl demo --mission`): the
# simulated world is fast and its vehicles are always there, so decide at once and ask for telemetry
# often (its timeouts are derived from the mock vehicles' speeds, as a real mission's are).
DEMO_SETTINGS = dict(time_limit=300.0, step_period=0.0, telemetry_hz=20.0)
DERIVED = "derived from the vehicle"  # the doc of the timing keys that follow each vehicle's speeds
DOC_BEGIN, DOC_END = "<!-- mission-spec:begin -->", "<!-- mission-spec:end -->"


# --- value types: files and connections -------------------------------------------------------------


def _file(value: Any, info: ValidationInfo) -> Path:
    if isinstance(value, Path):
        text = str(value)
    elif isinstance(value, str) and value:
        text = value
    else:
        raise SpecError("must be a file path string", "write the path in quotes, relative to the mission file")
    base = (info.context or {}).get("base", Path.cwd())
    path = (Path(base) / text).resolve()
    if not path.is_file():
        raise SpecError("names a file that does not exist", "fix the path (relative to the mission file)")
    return path


FilePath = Annotated[Path, PlainValidator(_file), PlainSerializer(str, when_used="json")]


def _connection(
    kinds: tuple[str, ...], rule: str, key: str, example: str, hint: str = "", port_zero: bool = False
) -> Any:
    """An Endpoint type taking a connection string of one of `kinds` (and port 0 only with
    `port_zero`); `rule`, with `key = example` as the fix, when not."""

    def parse(value: Any) -> Endpoint:
        fix = f'write for example {key} = "{example}"{hint}'
        if isinstance(value, Endpoint):
            endpoint = value
        elif isinstance(value, str):
            try:
                endpoint = parse_connection(value)
            except InputError as exc:
                why, _, _ = str(exc).removeprefix(f"connection {value!r}: ").partition("; ")
                raise SpecError(why, fix, example=example + hint) from None
        else:
            raise SpecError("must be a connection string", fix, example=example + hint)
        if endpoint.kind not in kinds or (endpoint.kind != "serial" and endpoint.port == 0 and not port_zero):
            raise SpecError(rule, fix, example=example + hint)
        return endpoint

    return Annotated[Endpoint, PlainValidator(parse), PlainSerializer(str, when_used="json")]


if TYPE_CHECKING:  # what the validators below give: an Endpoint
    VehicleLink = Endpoint
    SendTo = Endpoint
    GroundStation = Endpoint
    DetectorSocket = Endpoint
else:
    VehicleLink = _connection(
        ("udpin", "udpout", "tcp", "serial"),
        "is not a MAVLink connection",
        "connection",
        "udpin:0.0.0.0:14551",
        " (udpin, udpout, tcp HOST:PORT or a serial DEVICE:BAUD)",
        port_zero=True,  # udpin port 0: any free port (tests)
    )
    SendTo = _connection(
        ("udpout",),
        "is not a UDP address to send to",
        "channel",
        "udpout:127.0.0.1:14600",
        " (a MAVLink router or radio)",
    )
    GroundStation = _connection(
        ("udpout",),
        "is not a UDP address to send to",
        "gcs",
        "udpout:127.0.0.1:14550",
        " (QGroundControl listens there)",
    )
    DetectorSocket = _connection(("udpin",), "is not a local UDP socket", "detector", "udp:127.0.0.1:14650")

ON_LINK = "mavlink"  # a detector whose reports come on the vehicle's own MAVLink link
_SOCKET = TypeAdapter(DetectorSocket)


def _detector(value: Any) -> Endpoint | str:
    """ON_LINK, or a local UDP socket the detector sends its reports to."""
    if value == ON_LINK:
        return ON_LINK
    try:
        return _SOCKET.validate_python(value)
    except ValidationError:
        raise SpecError(
            f'is neither "{ON_LINK}" nor a local UDP socket (udp:HOST:PORT)',
            f'write detector = "{ON_LINK}" (reports on the vehicle\'s own link) or detector = "udp:127.0.0.1:14650"',
            example="udp:127.0.0.1:14650",
        ) from None


Detector = Annotated[Endpoint | str, PlainValidator(_detector), PlainSerializer(str, when_used="json")]

# `finish = "pos >= X"`: complete once the search's probability of success reaches X (swarmctl.mission.probability)
POS_FINISH = re.compile(r"^pos\s*>=\s*(\d+(?:\.\d*)?|\.\d+)$")
FINISH_FORMS = "held, found, covered or pos >= X (0 < X <= 1)"


def pos_goal(finish: str) -> float | None:
    """The probability of success a `pos >= X` finish line asks for; None for held, found and covered."""
    match = POS_FINISH.match(finish.strip())
    return float(match.group(1)) if match else None


def _finish(value: object) -> str:
    """held, found, covered, or "pos >= X" (written back as `pos >= X` with X as %g)."""
    if isinstance(value, str):
        text = value.strip()
        if text in FINISHES:
            return text
        goal = pos_goal(text)
        if goal is not None and 0.0 < goal <= 1.0:
            return f"pos >= {goal:g}"
    raise SpecError(
        f"must be {FINISH_FORMS}",
        'write for example finish = "covered", or finish = "pos >= X" with 0 < X <= 1 (e.g. "pos >= 0.9")',
        example="pos >= 0.9",
    )


MissionFinish = Annotated[str, PlainValidator(_finish)]


def parse_option(kind: Any, text: str, option: str) -> Any:
    """A command-line value parsed as the spec parses keys of this type (GroundStation,
    DetectorSocket, ...); InputError names the option."""
    try:
        return TypeAdapter(kind).validate_python(text)
    except ValidationError as exc:
        cause = (exc.errors()[0].get("ctx") or {}).get("error")
        if not isinstance(cause, SpecError):
            raise InputError(f"{option} {text!r}: not valid here") from None
        raise InputError(f"{option} {text!r}: {cause.rule}; give for example {option} {cause.example}") from None


def parse_detector(text: str, option: str = "--detector") -> Endpoint | str:
    """A detector given on the command line: ON_LINK or a local socket (udp:HOST:PORT)."""
    return parse_option(Detector, text, option)


# --- the tables ----------------------------------------------------------------------------------------


def setting(
    default: Any,
    meaning: str,
    *,
    ge: float | None = None,
    le: float | None = None,
    unit: str = "",
    example: Any = None,
    default_text: str | None = None,
    span: str | None = None,
    **extra: Any,
) -> Any:
    """A spec field: its default, meaning (the doc line), range (ge, le, unit; or `span`, the forms a
    value takes), an example for the fix, and `default_text` when the default is worked out later."""
    schema = {"unit": unit, "example": example, "default_text": default_text, "span": span}
    return Field(
        default,
        ge=ge,
        le=le,
        description=meaning,
        json_schema_extra={k: v for k, v in schema.items() if v not in (None, "")},
        **extra,
    )


class Table(BaseModel):
    """One table of the mission file: strict types, finite numbers, no unknown keys, immutable."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, allow_inf_nan=False)

    @classmethod
    def bounds(cls, key: str) -> tuple[Any, Any]:
        """The range (lowest, highest) of a number key."""
        return bounds(cls.model_fields[key])


class MissionTable(Table):
    """[mission]: what is searched, how high, with which policy, and how it ends."""

    name: str = setting(
        ...,
        "the mission's name, in the recording",
        pattern=NAME_PATTERN,
        span=NAME_SPAN,
        example="chicago-loop",
        default_text="the file's name",
    )
    id: int = setting(
        1, "mission id carried by every knowledge message (two swarms on one channel never mix)", ge=0, le=65535
    )
    grid: FilePath | None = setting(None, "a grid file from `swarmctl plan` (give grid or area)", example="grid.npz")
    area: FilePath | None = setting(
        None,
        "a search area (GeoJSON, KML, .plan) to grid at the mission's altitude and cell size",
        example="area.geojson",
    )
    buildings: FilePath | None = setting(
        None, "building footprints to block (with area only)", example="buildings.geojson"
    )
    cell_size: float | None = setting(
        None,
        "cell size; given with grid, it must be the grid's",
        ge=1.0,
        le=1000.0,
        unit="metres",
        example=DEFAULT_CELL,
        default_text=f"the grid's cell_size_m; with area, {DEFAULT_CELL:g}",
    )
    altitude: float | None = setting(
        None,
        "flight altitude; never below the grid's planning altitude (its blocked buildings are those "
        "at least that tall), above it is allowed and said",
        ge=2.0,
        le=500.0,
        unit="metres above home",
        example=DEFAULT_ALTITUDE,
        default_text=f"the grid's altitude_m; with area, {DEFAULT_ALTITUDE:g}",
    )
    footprint_m: float | None = setting(
        None,
        "radius of the disc the sensor covers round each cell reached; footprint_m / cell_size must be "
        "within 0.25 cell of the policy's fov (the one it was trained with)",
        ge=0.5,
        le=5000.0,
        unit="metres",
        example=30.0,
        default_text="the policy's fov x cell_size",
    )
    policy: str = setting(
        ...,
        "coordinated[:hover=first|defer], ddql:PATH[:options], ddql-greedy:PATH, la:N, frontier, lawnmower, random "
        "(PATH: from the mission file), "
        "or a search pattern from lkp: pattern:expanding-square, pattern:sector or pattern:parallel",
        min_length=1,
        example="frontier",
    )
    lkp: list[float] | None = setting(
        None,
        "the last known point [LAT, LON] (degrees) a pattern:NAME policy searches from; inside the grid",
        min_length=2,
        max_length=2,
        span="[LAT, LON]",
        example=[41.8819, -87.6278],
        default_text="none (needed by pattern:NAME)",
    )
    spacing_m: float | None = setting(
        None,
        "a pattern's track spacing (with lkp)",
        ge=1.0,
        le=100_000.0,
        unit="metres",
        example=60.0,
        default_text="the footprint's diameter, 2 x footprint_m",
    )
    end_action: EndAction = setting(
        "rtl", "at the end: land, rtl, or hover (vehicles on a target hold, the others come home)"
    )
    signing_key: FilePath | None = setting(
        None,
        "32-byte MAVLink 2 signing key file shared with the vehicles",
        example="swarm.key",
        default_text="none: unsigned",
    )
    gcs: GroundStation | None = setting(
        None,
        "forward the vehicles' MAVLink to this ground station",
        span="udpout:HOST:PORT",
        example="udpout:127.0.0.1:14550",
        default_text="none",
    )
    fence: bool = setting(False, "upload the area's boundary (plus one cell) to every vehicle as its geofence")
    allow_no_failsafe: bool = setting(
        False,
        "fly a vehicle whose GCS failsafe is off (ArduPilot FS_GCS_ENABLE 0, PX4 NAV_DLL_ACT 0: both their "
        "defaults), with a warning; false: preflight reads it and refuses such a vehicle before anything takes "
        "off, as then nothing brings it home if swarmctl stops",
    )
    finish: MissionFinish = setting(
        "held",
        "when the search is complete: held (expected_targets distinct targets hovered on by live vehicles), "
        "found (expected_targets targets known to the swarm; unknown: the area covered), covered (every "
        'cell the vehicles can reach explored) or "pos >= X" (the probability of success against the prior, '
        "with [sensing] pod, reaches X: 0 < X <= 1, 1 only with pod 1)",
        span=FINISH_FORMS,
        example="pos >= 0.9",
    )
    prior: FilePath | None = setting(
        None,
        "where the missing person is likely to be: a GeoJSON FeatureCollection of polygons, each with its "
        "`probability` (the rest spread evenly over the free cells in none) or all with a `weight` (per unit "
        "area), or an .npz with an array `prior` of the grid's shape (swarmctl.geo.prior)",
        example="prior.geojson",
        default_text="none: every free cell equally likely",
    )
    expected_targets: int | None = setting(
        None,
        "N, the targets the finish line counts (held: at most one a vehicle)",
        ge=1,
        le=MAX_EXPECTED_TARGETS,
        unit="targets",
        example=3,
        default_text="held: the vehicle count; found: unknown, so the area covered",
    )
    on_find: OnFind = setting(
        "hold",
        "what a vehicle does at a target it finds: hold (hover on it to the end) or mark (report it: a find "
        "event, a STATUSTEXT, the summary; and search on); mark needs finish found or covered",
    )
    confirm_finds: bool = setting(
        False,
        "held and found count only the finds an operator confirmed on the live page (--web); rejected finds "
        "are no targets either way",
    )

    @field_validator("policy")
    @classmethod
    def _model_path(cls, value: str, info: ValidationInfo) -> str:
        """A ddql model path, resolved relative to the mission file; it must exist (the plan loads it)."""
        kind, _, rest = value.strip().partition(":")
        if kind not in ("ddql", "ddql-greedy") or not rest:
            return value.strip()
        from swarmctl.policy.ddql import split_options

        model, options = split_options(rest)
        path = (Path((info.context or {}).get("base", Path.cwd())) / model).resolve()
        if not path.is_file():
            raise SpecError(
                f"names the model {model!r}, which does not exist", "fix the path (relative to the mission file)"
            )
        return f"{kind}:{path}{options}"

    @field_validator("lkp")
    @classmethod
    def _lat_lon(cls, value: list[float] | None) -> list[float] | None:
        if value is not None and not (-90.0 <= value[0] <= 90.0 and -180.0 <= value[1] <= 180.0):
            raise SpecError(
                "is not [LAT, LON] in degrees (latitude -90..90, longitude -180..180)",
                "write for example lkp = [41.8819, -87.6278]",
            )
        return value

    @model_validator(mode="after")
    def _pattern_and_lkp(self) -> MissionTable:
        from swarmctl.policy.routes import ROUTE_PATTERNS, ROUTE_PREFIX

        kind, _, rest = self.policy.partition(":")
        if kind == ROUTE_PREFIX:
            name = rest.split(":")[0]
            if name not in ROUTE_PATTERNS:
                forms = ", ".join(f'"{ROUTE_PREFIX}:{p}"' for p in ROUTE_PATTERNS)
                raise SpecError("is not a search pattern", f"write policy = one of {forms}", ("policy",), self.policy)
            if self.lkp is None:
                raise SpecError(
                    "searches from a last known point, and lkp is missing",
                    "add lkp = [LAT, LON] (degrees, inside the grid) to [mission]",
                    ("policy",),
                    self.policy,
                )
        else:
            for key in ("lkp", "spacing_m"):
                if getattr(self, key) is not None:
                    raise SpecError(
                        f"is for a search pattern, and policy = {self.policy!r} is none",
                        f'write policy = "{ROUTE_PREFIX}:parallel" (or {", ".join(ROUTE_PATTERNS[:-1])}), '
                        f"or leave {key} out",
                        (key,),
                        getattr(self, key),
                    )
        return self

    @model_validator(mode="after")
    def _grid_or_area(self) -> MissionTable:
        if self.grid is not None and self.area is not None:
            raise SpecError(
                "is given together with area", "give either grid (from `swarmctl plan`) or area", ("grid",), self.grid
            )
        if self.buildings is not None and self.area is None:
            raise SpecError(
                "needs area",
                "give area with buildings, or plan a grid with `swarmctl plan --buildings`",
                ("buildings",),
                self.buildings,
            )
        if self.finish == "held" and self.on_find == "mark":
            raise SpecError(
                'contradicts finish = "held" (a marking vehicle never hovers on a target, so none is held)',
                'write finish = "found" or finish = "covered" with on_find = "mark", or on_find = "hold"',
                ("on_find",),
                self.on_find,
            )
        return self


class TimingTable(Table):
    """[timing]: the pace of the search and how long each stage may take."""

    step_period: float = setting(1.0, "time between decisions, at least", ge=0.0, le=60.0, unit="seconds")
    step_timeout: float | None = setting(
        None,
        "time to reach the next cell before the step is given up",
        ge=0.1,
        le=600.0,
        unit="seconds",
        example=30.0,
        default_text=f"{DERIVED}: 2 x the move at its speed parameters + 5 s",
    )
    time_limit: float = setting(900.0, "time for the whole search", ge=1.0, le=86400.0, unit="seconds")
    connect_timeout: float = setting(20.0, "wait for a vehicle's first heartbeat", ge=0.1, le=600.0, unit="seconds")
    ready_timeout: float = setting(
        120.0,
        "wait for a vehicle to be ready to arm in the mode it is flown in (ArduPilot: GUIDED, GPS fix, "
        "the EKF's position, home, pre-arm checks; ArduCopter SITL takes 42 s)",
        ge=0.1,
        le=3600.0,
        unit="seconds",
    )
    takeoff_timeout: float | None = setting(
        None,
        "wait for a take-off to reach the altitude, and again for the first cell",
        ge=1.0,
        le=3600.0,
        unit="seconds",
        example=120.0,
        default_text=f"{DERIVED}: 2 x (spool-up + the climb at its climb rate) + 5 s; the first cell as a step",
    )
    sense_timeout: float = setting(
        5.0, "wait for the detector's report after reaching a cell", ge=0.0, le=60.0, unit="seconds"
    )
    end_timeout: float | None = setting(
        None,
        "wait for the vehicles to land after the end action (0: do not wait)",
        ge=0.0,
        le=3600.0,
        unit="seconds",
        example=180.0,
        default_text=f"{DERIVED}: 2 x (its return and landing at its speed parameters) + 5 s",
    )


class FlightTable(Table):
    """[flight]: how the vehicles are flown."""

    takeoff_at_once: int = setting(
        1, "vehicles climbing at the same time (1: one after the other)", ge=1, le=250, unit="vehicles"
    )
    reach_tolerance: float = setting(
        0.5, "distance from a cell centre that counts as arrived", ge=0.05, le=50.0, unit="metres"
    )
    telemetry_hz: float = setting(
        5.0, "GLOBAL_POSITION_INT rate asked of ArduPilot vehicles", ge=0.2, le=50.0, unit="Hz"
    )
    off_course_m: float = setting(
        10.0,
        "distance from the path of its last step (to the centre of the cell it was sent to, from the centre of "
        "the cell it held or from where it last was on course) beyond which a vehicle is off course: flagged "
        "and sent its setpoint again",
        ge=1.0,
        le=1000.0,
        unit="metres",
    )
    below_altitude_m: float = setting(
        5.0,
        "how far below the mission altitude a searching or hovering vehicle is off course",
        ge=0.5,
        le=1000.0,
        unit="metres",
    )
    off_course_rounds: int = setting(
        3,
        "decision rounds in a row a vehicle may be off course before it is treated as taken over (no longer "
        "commanded; the others carry on)",
        ge=1,
        le=1000,
        unit="rounds",
    )


class BatteryTable(Table):
    """[battery]: charge thresholds, in % of a full battery as the vehicle reports it."""

    takeoff_min: int = setting(30, "charge a vehicle needs in preflight to start", ge=0, le=100, unit="%")
    return_below: int = setting(
        15, "charge below which a searching vehicle is sent home (RTL) whatever its distance", ge=0, le=100, unit="%"
    )
    reserve: int = setting(
        15,
        "charge a vehicle must still have when it lands at home: it is sent home once its charge is below this "
        "plus what its return takes at its measured consumption",
        ge=0,
        le=100,
        unit="%",
    )
    relaunch: bool = setting(
        True,
        "a vehicle sent home on low battery that reports at least takeoff_min again, landed and disarmed (a "
        "fresh battery), takes off and rejoins the search; a vehicle the pilot took over or the operator sent "
        "home stays down either way",
        example=False,
    )

    @model_validator(mode="after")
    def _ordered(self) -> BatteryTable:
        if self.return_below > self.takeoff_min:
            raise SpecError(
                f"is above takeoff_min = {self.takeoff_min}, so vehicles would be sent home as they start",
                "make return_below at most takeoff_min",
                ("return_below",),
                self.return_below,
            )
        return self


class KnowledgeTable(Table):
    """[knowledge]: how the agents share what they know (TUNNEL messages)."""

    channel: SendTo | None = setting(
        None,
        "where agents in separate processes (`swarmctl agent`) send their TUNNEL messages: a MAVLink router or "
        "telemetry mesh that forwards them to every agent; `swarmctl fly` shares in its own process and needs none",
        span="udpout:HOST:PORT",
        example="udpout:127.0.0.1:14600",
        default_text="none (needed by `swarmctl agent`)",
    )
    digest_every: int = setting(5, "steps between digests of what an agent knows", ge=1, le=1000, unit="steps")
    push: bool | None = setting(
        None,
        "send the cells a peer's digest lacks at once (with many vehicles on one channel every digest "
        "sets off a push from each receiver)",
        example=True,
        default_text=f"on for up to {PUSH_UP_TO} vehicles",
    )


class SensingTable(Table):
    """[sensing]: how well the detector sees."""

    pod: float = setting(
        1.0,
        "probability of detection: the chance a target is seen in one pass (its entry into a vehicle's "
        "footprint); below 1 a cell seen once may still hold the target, which the "
        "search's POS and the planner's density count (held, found and covered count a cell seen once)",
        ge=0.0,
        le=1.0,
        example=0.8,
    )

    @field_validator("pod")
    @classmethod
    def _positive(cls, value: float) -> float:
        if value <= 0.0:
            raise SpecError("must be above 0 (a detector that never sees)", "give pod in (0, 1], e.g. pod = 0.8")
        return value


CONNECTION_PLACEHOLDER = "FILL IN"  # the connection `swarmctl plan` writes into a mission file, to be replaced


class VehicleSpec(Table):
    """[[vehicles]]: one vehicle of the swarm; its index in the list is its index in the mission."""

    @model_validator(mode="before")
    @classmethod
    def _filled_in(cls, data: object) -> object:
        """A connection still the placeholder `swarmctl plan` wrote: say which vehicle's to fill in."""
        if isinstance(data, dict) and data.get("connection") == CONNECTION_PLACEHOLDER:
            name = data.get("name")
            which = f"vehicle {name!r}" if isinstance(name, str) else "this vehicle"
            raise SpecError(
                f"is the placeholder `swarmctl plan` wrote: fill in the connection of {which}",
                'write its MAVLink link, e.g. connection = "udpin:0.0.0.0:14551" (udpin, udpout, tcp HOST:PORT or '
                "a serial DEVICE:BAUD)",
                ("connection",),
                CONNECTION_PLACEHOLDER,
            )
        return data

    name: str = setting(..., "the vehicle's name", pattern=NAME_PATTERN, span=NAME_SPAN, example="alpha")
    connection: VehicleLink = setting(
        ...,
        "its MAVLink connection",
        span="udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, DEVICE:BAUD",
        example="udpin:0.0.0.0:14551",
    )
    sysid: int = setting(
        ...,
        "its MAVLink system id (ArduPilot 4.7: MAV_SYSID, before: SYSID_THISMAV; PX4: MAV_SYS_ID); unique in the swarm",
        ge=1,
        le=250,
        example=1,
    )
    autopilot: AutopilotName | None = setting(
        None,
        "the firmware it must run; a vehicle whose heartbeat says otherwise is refused",
        example="ardupilot",
        default_text="as its heartbeat says",
    )
    detector: Detector | None = setting(
        None,
        'its detector: "mavlink" (reports on its own MAVLink link) or the local socket it reports to; '
        "the controller waits for a report after each cell reached (sense_timeout)",
        span='"mavlink", udp:HOST:PORT',
        example="mavlink",
        default_text="none: a coverage search (cells explored from its position, nothing to find)",
    )


class MissionSpec(Table):
    """A whole mission file."""

    mission: MissionTable = setting(..., "a [mission] table with at least policy and grid or area")
    timing: TimingTable = Field(default_factory=TimingTable, description="timing")
    flight: FlightTable = Field(default_factory=FlightTable, description="flight")
    battery: BatteryTable = Field(default_factory=BatteryTable, description="battery")
    knowledge: KnowledgeTable = Field(default_factory=KnowledgeTable, description="knowledge sharing")
    sensing: SensingTable = Field(default_factory=SensingTable, description="sensing")
    vehicles: list[VehicleSpec] = setting(
        ..., "one [[vehicles]] table per vehicle (name, connection, sysid)", min_length=1, max_length=250
    )

    @model_validator(mode="after")
    def _distinct_vehicles(self) -> MissionSpec:
        for i, v in enumerate(self.vehicles):
            for other in self.vehicles[:i]:
                if other.name == v.name:
                    raise SpecError(
                        "is listed twice", "give every vehicle its own name", ("vehicles", i, "name"), v.name
                    )
                if other.sysid == v.sysid:
                    raise SpecError(
                        f"is also the system id of {other.name!r}",
                        "system ids must be unique in a swarm (ArduPilot's MAV_SYSID, PX4's MAV_SYS_ID)",
                        ("vehicles", i, "sysid"),
                        v.sysid,
                    )
        m = self.mission
        if pos_goal(m.finish) == 1.0 and self.sensing.pod < 1.0:
            raise SpecError(
                f"can never be reached with [sensing] pod = {self.sensing.pod:g} (a cell is never certainly clear)",
                'write a goal below 1, e.g. finish = "pos >= 0.95", or pod = 1.0',
                ("mission", "finish"),
                m.finish,
            )
        if m.finish == "held" and m.expected_targets is not None and m.expected_targets > len(self.vehicles):
            raise SpecError(
                f"is more than the {len(self.vehicles)} vehicle(s) listed, and a vehicle holds one target",
                f'write expected_targets = {len(self.vehicles)} at most, or finish = "found" to count targets '
                "found without holding them",
                ("mission", "expected_targets"),
                m.expected_targets,
            )
        return self

    @classmethod
    def build(
        cls, vehicles: list[VehicleSpec], base: MissionSpec | None = None, where: str = "mission", **settings: Any
    ) -> MissionSpec:
        """A spec made in code (the demo): `base`'s tables (or the defaults) with `settings` (flat key
        names, each routed to its table; None puts a key back to its default) and `vehicles`,
        validated like a file; InputError names `where`."""
        data: dict[str, Any] = {t: dict(getattr(base, t)) if base else {} for t in SETTING_TABLES}
        for key, value in settings.items():
            if key not in TABLE_OF:
                raise TypeError(f"{key!r} is not a mission setting")
            if value is None:
                data[TABLE_OF[key]].pop(key, None)
            else:
                data[TABLE_OF[key]][key] = value
        data["vehicles"] = list(vehicles)
        return validate(data, where)


TABLES: dict[str, type[Table]] = {
    "mission": MissionTable,
    "timing": TimingTable,
    "flight": FlightTable,
    "battery": BatteryTable,
    "knowledge": KnowledgeTable,
    "sensing": SensingTable,
    "vehicles": VehicleSpec,
}
SETTING_TABLES = tuple(t for t in TABLES if t != "vehicles")
TABLE_OF = table_of_key(MissionSpec)  # a setting's flat name -> its table
if len(TABLE_OF) != sum(len(TABLES[t].model_fields) for t in SETTING_TABLES):
    raise RuntimeError("two tables of the mission spec have a key of the same name")


# --- reading and errors ----------------------------------------------------------------------------------


def load_spec(path: str | Path) -> MissionSpec:
    """Read and validate a mission file; every problem is an InputError of one line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such mission file")
    with path.open("rb") as fh:
        raw = fh.read(MAX_BYTES + 1)
    if len(raw) > MAX_BYTES:
        raise InputError(f"{path}: over {MAX_BYTES // 1000} kB, too large for a mission file; give the mission's TOML")
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file; a mission file is TOML") from None
    except tomllib.TOMLDecodeError as exc:
        why = " ".join(str(exc).split())
        raise InputError(f"{path}: not valid TOML ({why}); fix the syntax there") from None
    mission = data.get("mission")
    if isinstance(mission, dict) and "name" not in mission:
        mission["name"] = re.sub(r"[^A-Za-z0-9_.-]", "-", path.stem).lstrip("-_.") or "mission"
    spec = validate(data, str(path), base=path.resolve().parent)
    if spec.mission.grid is None and spec.mission.area is None:
        raise InputError(f"{path}: mission.grid is missing; give grid (from `swarmctl plan`) or area")
    return spec


def validate(data: dict, where: str, base: Path | None = None) -> MissionSpec:
    """A MissionSpec from parsed TOML (or the same shape in code); InputError names `where`."""
    try:
        return MissionSpec.model_validate(data, context={"base": base} if base is not None else None)
    except ValidationError as exc:
        raise InputError(f"{where}: {explain(exc.errors()[0], MissionSpec)}") from None


def main(argv: list[str] | None = None) -> None:
    """`python -m swarmctl.mission.spec --markdown | --write docs/mission.md`."""
    ap = argparse.ArgumentParser(description="The mission file's keys, as a Markdown table.")
    ap.add_argument("--markdown", action="store_true", help="print the table")
    ap.add_argument("--write", type=Path, help="replace the table between the markers in this file")
    args = ap.parse_args(argv)
    if args.write:
        changed = replace_between(args.write, DOC_BEGIN, DOC_END, markdown_table(MissionSpec))
        print(f"{args.write}: {'updated' if changed else 'already up to date'}")
    if args.markdown or not args.write:
        sys.stdout.write(markdown_table(MissionSpec) + "\n")


if __name__ == "__main__":
    main()
