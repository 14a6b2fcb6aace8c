"""Real ArduCopter SITL instances for the tests: start them in parallel, wait on them, always stop them.

The binary comes from the environment variable ARDUPILOT_SITL (SWARMCTL_ARDUCOPTER, its older name, is
read too), by default ../shared/sitl/arducopter beside the repository, with ArduPilot's copter.parm next
to it; without it the tests are skipped with the reason. Each instance runs in a temporary folder of its
own (a fresh one is fresh parameters), removed when it stops. Instance N (the tests use 0-4, system
id N+1) listens on TCP 5760+10N (SERIAL0; it waits for a client there before it boots), 5762+10N and
5763+10N once booted.

The process helpers here (SimProcess, wait_until, stop_all, the /proc/net port checks and the plain
pymavlink client) serve tests/px4_support.py too.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"

ARDUCOPTER_ENV = ("ARDUPILOT_SITL", "SWARMCTL_ARDUCOPTER")  # the first one set wins
ARDUCOPTER_DEFAULT = SHARED / "sitl" / "arducopter"
ARDUCOPTER_INSTANCES = tuple(range(5))  # ArduCopter -I 0-4 with --sysid 1-5
CHICAGO_HOME = (41.879653, -87.635357, 180.0, 0.0)  # lat, lon, alt AMSL, heading: the Chicago Loop take-off point

STOP_GRACE_S = 5.0  # SIGTERM, then SIGKILL after this long
POLL_S = 0.05


class SitlError(RuntimeError):
    """A SITL instance could not be started, or did not get where a test waited for it to get."""


# --- binaries -----------------------------------------------------------------------------------------


def _names(env: str | Sequence[str]) -> tuple[str, ...]:
    return (env,) if isinstance(env, str) else tuple(env)


def binary_path(env: str | Sequence[str], default: Path) -> Path:
    """The binary named by the first of the environment variables `env` that is set, else `default` (it
    may not exist)."""
    for name in _names(env):
        value = os.environ.get(name, "").strip()
        if value:
            return Path(value).expanduser().resolve()
    return default


def missing_binary(env: str | Sequence[str], default: Path, what: str) -> str | None:
    """Why the binary cannot be run (a skip reason naming the path and the variable), or None."""
    path = binary_path(env, default)
    if path.is_file() and os.access(path, os.X_OK):
        return None
    given = [name for name in _names(env) if os.environ.get(name, "").strip()]
    source = f"from ${given[0]}" if given else f"the default; set ${_names(env)[0]} to use another"
    return f"no {what} at {path} ({source})"


def require_binary(env: str | Sequence[str], default: Path, what: str) -> Path:
    """The binary's path; skips the calling test with the reason when it is not an executable file."""
    why = missing_binary(env, default, what)
    if why is not None:
        pytest.skip(why)
    return binary_path(env, default)


def arducopter_missing() -> str | None:
    """Why ArduCopter SITL cannot be run here (the binary or the copter.parm beside it is missing), or None."""
    why = missing_binary(ARDUCOPTER_ENV, ARDUCOPTER_DEFAULT, "ArduCopter SITL binary")
    binary = binary_path(ARDUCOPTER_ENV, ARDUCOPTER_DEFAULT)
    if why is None and not (binary.parent / "copter.parm").is_file():
        why = f"no copter.parm beside the ArduCopter SITL binary {binary}"
    return why


def require_arducopter() -> tuple[Path, Path]:
    """The ArduCopter SITL binary and the copter.parm beside it; skips the test when either is missing."""
    why = arducopter_missing()
    if why is not None:
        pytest.skip(why)
    binary = binary_path(ARDUCOPTER_ENV, ARDUCOPTER_DEFAULT)
    return binary, binary.parent / "copter.parm"


# --- ports (from /proc/net: looking never disturbs a listener) ------------------------------------------

_TCP_LISTEN = "0A"


def _local_ports(kind: str, state: str | None = None) -> set[int]:
    ports: set[int] = set()
    for name in (kind, kind + "6"):
        try:
            lines = Path("/proc/net", name).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 3 and (state is None or fields[3] == state):
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def tcp_listening(port: int) -> bool:
    """True when some process listens on TCP `port` (accepts connections)."""
    return port in _local_ports("tcp", _TCP_LISTEN)


def udp_bound(port: int) -> bool:
    """True when some process has a UDP socket bound to `port`."""
    return port in _local_ports("udp")


# --- processes ------------------------------------------------------------------------------------------


@dataclass
class SimProcess:
    """One simulator process, its console (stdout and stderr) in console.txt in its own folder."""

    name: str
    argv: list[str]
    folder: Path
    env: dict[str, str] | None = None
    process: subprocess.Popen | None = None
    started_at: float = 0.0  # time.monotonic()

    @property
    def console_path(self) -> Path:
        return self.folder / "console.txt"

    def start(self) -> SimProcess:
        """Make its folder and launch the process there (in a session of its own, so that its children
        stop with it)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        env = None if self.env is None else {**os.environ, **self.env}
        with open(self.console_path, "wb") as console:
            self.process = subprocess.Popen(
                self.argv,
                cwd=self.folder,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=console,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.started_at = time.monotonic()
        return self

    @property
    def pid(self) -> int:
        assert self.process is not None
        return self.process.pid

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def console(self) -> str:
        try:
            return self.console_path.read_text(errors="replace")
        except OSError:
            return ""

    def console_tail(self, chars: int = 1500) -> str:
        return self.console()[-chars:]

    def cpu_seconds(self) -> float:
        """User + system CPU time the process has used so far (from /proc/PID/stat)."""
        fields = Path(f"/proc/{self.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def check_alive(self, waiting_for: str) -> None:
        if self.process is not None and self.process.poll() is not None:
            raise SitlError(
                f"{self.name} exited with {self.process.returncode} while waiting for {waiting_for}; "
                f"its console ends:\n{self.console_tail()}"
            )


def wait_until(condition: Callable[[], bool], timeout: float, what: str, processes: Sequence[SimProcess] = ()) -> float:
    """Wait until condition() holds (checked every 50 ms); SitlError when one of `processes` exits first or
    after `timeout` seconds. Returns the seconds waited."""
    start = time.monotonic()
    while not condition():
        for p in processes:
            p.check_alive(what)
        if time.monotonic() - start > timeout:
            tails = "".join(f"\n--- {p.name} console ends:\n{p.console_tail(600)}" for p in processes)
            raise SitlError(f"timed out after {timeout:g} s waiting for {what}{tails}")
        time.sleep(POLL_S)
    return time.monotonic() - start


def stop_all(processes: Sequence[SimProcess], grace: float = STOP_GRACE_S) -> None:
    """SIGTERM every process at once, wait up to `grace` seconds, then SIGKILL what is left. Each
    process's session (its children) is killed too. Returns when every process has been reaped."""
    started = [p for p in processes if p.process is not None]
    for p in started:
        if p.alive():
            with contextlib.suppress(ProcessLookupError):
                p.process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for p in started:
        try:
            p.process.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                p.process.kill()
            p.process.wait()
        for pid in session_members(p.pid):  # children it left behind (e.g. PX4's start-up shell)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)


def session_members(session: int) -> list[int]:
    """The ids of the live processes in session `session` (a process started with start_new_session)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == session and fields[0] != "Z":
            members.append(int(stat.parent.name))
    return members


# --- ArduCopter -----------------------------------------------------------------------------------------


@dataclass
class ArduCopterSitl:
    """One running ArduCopter SITL instance."""

    instance: int
    sysid: int
    home: tuple[float, float, float, float]
    proc: SimProcess

    @property
    def port(self) -> int:
        """SERIAL0, the port a controller connects to."""
        return 5760 + 10 * self.instance

    @property
    def ports(self) -> tuple[int, int, int]:
        """SERIAL0, SERIAL1, SERIAL2 (the last two open once the instance has booted)."""
        return (self.port, self.port + 2, self.port + 3)

    @property
    def connection(self) -> str:
        """The mission file's connection string for SERIAL0."""
        return f"tcp:127.0.0.1:{self.port}"


def arducopter_ports(instance: int) -> tuple[int, int, int]:
    """Instance N's TCP ports: SERIAL0, SERIAL1, SERIAL2."""
    return (5760 + 10 * instance, 5762 + 10 * instance, 5763 + 10 * instance)


def arducopter_busy(instance: int) -> str | None:
    """Why ArduCopter instance number `instance` cannot be used now (None when it can)."""
    listening = _local_ports("tcp", _TCP_LISTEN)
    taken = [port for port in arducopter_ports(instance) if port in listening]
    return f"TCP {taken[0]} is in use" if taken else None


def free_arducopter_instances(count: int) -> list[int]:
    """`count` instance numbers of ARDUCOPTER_INSTANCES whose TCP ports nobody listens on."""
    free = [n for n in ARDUCOPTER_INSTANCES if arducopter_busy(n) is None]
    if len(free) < count:
        raise SitlError(
            f"{count} ArduCopter SITL instances wanted but only {free} of {list(ARDUCOPTER_INSTANCES)} are free "
            "(TCP 5760+10N in use): stop the other SITL runs"
        )
    return free[:count]


@contextlib.contextmanager
def arducopter_sitl(
    count: int = 1,
    *,
    homes: Sequence[tuple[float, float, float, float]] | None = None,
    speedup: float = 1.0,
    instances: Sequence[int] | None = None,
    timeout: float = 30.0,
    params: Mapping[str, float] | None = None,
    extra_args: Sequence[str] = (),
) -> Iterator[list[ArduCopterSitl]]:
    """Start `count` ArduCopter SITL instances in parallel (free instance numbers from the table unless
    given; home `CHICAGO_HOME` unless given, one per instance) and yield them once each listens on
    SERIAL0. `params` are defaults on top of copter.parm (e.g. BATT_CAPACITY: SITL's simulated 3300 mAh
    reads 15 % after about 6 minutes in the air). Every instance is stopped and its folder removed on the
    way out, whatever happened."""
    binary, parm = require_arducopter()
    chosen = list(instances) if instances is not None else free_arducopter_instances(count)
    with sim_run("swarmctl-arducopter-") as (root, procs):
        copters: list[ArduCopterSitl] = []
        defaults = str(parm)
        if params:
            extra = root / "extra.parm"
            extra.write_text("".join(f"{name} {float(value)!r}\n" for name, value in params.items()))
            defaults += f",{extra}"
        for n, home in homes_for(chosen, homes, CHICAGO_HOME):
            argv = [str(binary), "--model", "+", "--speedup", f"{speedup:g}", "--defaults", defaults]
            argv += ["-I", str(n), "--sysid", str(n + 1), "--home", ",".join(repr(float(v)) for v in home)]
            procs.append(SimProcess(f"ArduCopter SITL -I {n}", argv + list(extra_args), root / f"I{n}").start())
            copters.append(ArduCopterSitl(n, n + 1, home, procs[-1]))
        ports = ", ".join(str(c.port) for c in copters)
        wait_until(lambda: all(tcp_listening(c.port) for c in copters), timeout, f"SERIAL0 on {ports}", procs)
        yield copters


@contextlib.contextmanager
def sim_run(prefix: str) -> Iterator[tuple[Path, list[SimProcess]]]:
    """A temporary folder and the list of the processes started in it: on the way out, whatever
    happened, every process in the list is stopped (stop_all) and the folder removed."""
    root = Path(tempfile.mkdtemp(prefix=prefix))
    procs: list[SimProcess] = []
    try:
        yield root, procs
    finally:
        stop_all(procs)
        shutil.rmtree(root, ignore_errors=True)


def homes_for(instances: Sequence[int], homes: Sequence[tuple] | None, default: tuple) -> list[tuple[int, tuple]]:
    """(instance, home) pairs: `homes` one per instance, or `default` for all."""
    homes = list(homes) if homes is not None else [default] * len(instances)
    if len(homes) != len(instances):
        raise ValueError(f"{len(instances)} instances but {len(homes)} homes")
    return [(n, tuple(home)) for n, home in zip(instances, homes)]


# --- plain pymavlink client -----------------------------------------------------------------------------


@contextlib.contextmanager
def mavlink_client(connection: str, *, source_system: int = 255, source_component: int = 190) -> Iterator[Any]:
    """A pymavlink connection (e.g. "tcp:127.0.0.1:5760", "udpin:0.0.0.0:14545"), closed on the way out."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(
        connection, source_system=source_system, source_component=source_component, dialect="ardupilotmega"
    )
    conn.mav.robust_parsing = True  # console text before MAVLink arrives as BAD_DATA, not an exception
    try:
        yield conn
    finally:
        conn.close()


def wait_message(
    conn: Any,
    mtype: str | Sequence[str],
    timeout: float,
    *,
    sysid: int | None = None,
    condition: Callable[[Any], bool] | None = None,
    every: Callable[[], None] | None = None,
    every_s: float = 1.0,
) -> Any:
    """The next message of type `mtype` (from system `sysid`, satisfying `condition`); SitlError after
    `timeout` seconds. `every()` is called at once and then every `every_s` seconds while waiting (e.g.
    to repeat a request the vehicle may have lost)."""
    types = [mtype] if isinstance(mtype, str) else list(mtype)
    start = time.monotonic()
    next_call = start
    while True:
        now = time.monotonic()
        if every is not None and now >= next_call:
            every()
            next_call = now + every_s
        left = timeout - (now - start)
        if left <= 0:
            raise SitlError(f"no {'/'.join(types)} from {conn.address} within {timeout:g} s")
        wait = min(left, max(0.01, next_call - now)) if every is not None else left
        msg = conn.recv_match(type=types, blocking=True, timeout=min(wait, 0.5))
        if msg is None:
            continue
        if sysid is not None and msg.get_srcSystem() != sysid:
            continue
        if condition is None or condition(msg):
            return msg


def request_message_interval(conn: Any, sysid: int, message_id: int, rate_hz: float, compid: int = 1) -> None:
    """Send MAV_CMD_SET_MESSAGE_INTERVAL (COMMAND_LONG) once; the caller waits for the stream."""
    from pymavlink import mavutil

    interval_us = 1e6 / rate_hz if rate_hz > 0 else -1.0
    conn.mav.command_long_send(
        sysid, compid, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, float(message_id), interval_us, 0, 0, 0, 0, 0
    )


def read_param(conn: Any, sysid: int, name: str, timeout: float = 10.0, compid: int = 1) -> float:
    """A parameter's value by PARAM_REQUEST_READ (repeated each second until PARAM_VALUE answers)."""
    ask = lambda: conn.mav.param_request_read_send(sysid, compid, name.encode(), -1)  # noqa: E731
    answer = wait_message(
        conn, "PARAM_VALUE", timeout, sysid=sysid, condition=lambda m: m.param_id.rstrip("\x00") == name, every=ask
    )
    return float(answer.param_value)
