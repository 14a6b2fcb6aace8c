"""What the parts of a mock autopilot (mock_telemetry, mock_flight, mock_commands) share: the vehicle's
state and the operations one part calls on another, declared here for the type checker. MockAutopilot
(swarmctl.sim.autopilot) sets the state and defines the operations; the personalities
(swarmctl.sim.personality) see the mock through this class too."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:  # pragma: no cover
    from swarmctl.sim.autopilot import MockAutopilot
    from swarmctl.sim.boot import Boot
    from swarmctl.sim.fence import MockFence
    from swarmctl.sim.personality import Personality

K = TypeVar("K")


def dropping(drops: dict[K, int | None], key: K) -> bool:
    """Whether this message is one to drop (`drops`: key -> how many more, None: all), counting it."""
    if key not in drops:
        return False
    left = drops[key]
    if left is None or left > 1:
        drops[key] = None if left is None else left - 1
    else:
        del drops[key]
    return True


class MockBase:
    """The declarations MockAutopilot's parts type-check against (annotations only: no attribute is set
    here, so the behaviour is MockAutopilot's)."""

    # configuration (MockAutopilot.__init__)
    personality: Personality
    sysid: int
    home: tuple[float, float, float]  # lat, lon, alt AMSL
    speed: float
    climb_rate: float
    descent_rate: float
    rtl_alt: float
    battery_drain: float
    gcs_failsafe_timeout: float | None
    reposition_frames: frozenset[int] | None
    tunnel_handler: Callable[[MockAutopilot, Any], None] | None
    mav: Any  # pymavlink's MAVLink (untyped); None before start()
    fence: MockFence
    params: dict[str, float]
    # faults
    arming_refusal: str | None
    forced_results: dict[int, int]
    _no_heartbeat_until: float
    _glitch: tuple[float, float, float] | None
    _drop_commands: dict[int, int | None]
    _drop_received: dict[str, int | None]
    _forget: dict[int, int]
    _console_after_heartbeat: bytes
    # observation for tests
    received: deque[tuple[str, int, int]]
    ignored: int
    # the state (MockAutopilot._boot)
    boot_wall: float
    sim_time: float
    lat: float
    lon: float
    rel_alt: float
    vel: tuple[float, float, float]  # north, east, down m/s
    armed: bool
    custom_mode: int
    target: tuple[float, float, float] | None  # lat, lon, rel_alt
    battery: float
    boot: Boot
    _prearm_shown: tuple[str | None, float]
    last_gcs_heartbeat: float | None
    gcs_failsafe: bool
    _failsafe_done: bool
    last_setpoint: float
    intervals: dict[int, float]
    next_due: dict[int, float]
    next_heartbeat: float

    if TYPE_CHECKING:  # pragma: no cover

        @property
        def ready(self) -> bool: ...

        @property
        def home_set(self) -> bool: ...

        @property
        def mode_name(self) -> str: ...

        def reboot(self, downtime: float = 1.0) -> None: ...

        def send_message(self, msg: Any) -> None: ...

        def statustext(self, text: str, severity: int = ...) -> None: ...

        def _write(self, buf: bytes) -> None: ...

        def _ack(self, msg: Any, command: int, result: int) -> None: ...

        def _build(self, msg_id: int) -> Any: ...  # mock_telemetry

        def _not_armable(self) -> str | None: ...  # mock_flight

        def _set_mode_name(self, name: str) -> int: ...  # mock_commands
