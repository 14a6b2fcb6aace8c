"""Real PX4 SITL instances (SIH physics, no simulator process) for the tests: start, wait on, stop.

The binary comes from the environment variable PX4_SITL (SWARMCTL_PX4, its older name, is read too), by
default ../shared/px4/bin/px4 beside the repository, its start-up scripts in ../etc beside bin/; without
it the tests are skipped with the reason. PX4's shell runs its commands as `px4-NAME` links to the binary
found beside it; a copy may have lost them (../shared has them as 3-byte files), so each run builds a
bin/ folder of its own: a link to the binary, px4-alias.sh and one px4-NAME link per alias in it.

Instance N (the tests use 5-9, system id N+1) sends its ground-station link from UDP 18570+N to
127.0.0.1:14550 and its API (offboard) link from 14580+N to 127.0.0.1:14540+N: a client listens on
`udpin:0.0.0.0:14540+N`. PX4 holds /tmp/px4_lock-N while it runs and leaves /tmp/px4-sock-N behind;
a run picks instance numbers nobody holds and removes what its own instances left there.
"""

from __future__ import annotations

import contextlib
import fcntl
import re
import shutil
import subprocess
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.sitl_support import (
    SHARED,
    SimProcess,
    SitlError,
    binary_path,
    homes_for,
    missing_binary,
    sim_run,
    udp_bound,
    wait_until,
)

PX4_ENV = ("PX4_SITL", "SWARMCTL_PX4")  # the first one set wins
PX4_DEFAULT = SHARED / "px4" / "bin" / "px4"
PX4_INSTANCES = tuple(range(5, 10))  # PX4 -i 5-9 (system id 6-10)
PX4_HOME = (41.879653, -87.635357, 180.0)  # lat, lon, alt AMSL: the Chicago Loop take-off point
# SIM_BAT_DRAIN: PX4's simulated battery empties in 60 s by default (to SIM_BAT_MIN_PCT 50 %, where it
# holds), a drain no vehicle has: the controller's energy rule (swarmctl.mission.energy) measures it and
# rightly sends the vehicle home within a minute. 1800 s is a search quadcopter's half hour.
PX4_ENV_VARS = {
    "PX4_SYS_AUTOSTART": "10040",
    "PX4_SIMULATOR": "sihsim",
    "PX4_SIM_MODEL": "sihsim_quadx",
    "PX4_PARAM_SIM_BAT_DRAIN": "1800",
}
AUTOPILOT_PX4 = 12  # MAV_AUTOPILOT_PX4
_ALIAS = re.compile(r"^alias ([A-Za-z_0-9]+)=", re.MULTILINE)


def lock_file(instance: int) -> Path:
    return Path(f"/tmp/px4_lock-{instance}")


def socket_file(instance: int) -> Path:
    return Path(f"/tmp/px4-sock-{instance}")


def px4_missing() -> str | None:
    """Why PX4 SITL cannot be run here (the binary or its etc/ start-up scripts are missing), or None."""
    why = missing_binary(PX4_ENV, PX4_DEFAULT, "PX4 SITL binary")
    binary = binary_path(PX4_ENV, PX4_DEFAULT)
    etc = binary.parent.parent / "etc"
    if why is None and not (etc / "init.d-posix" / "rcS").is_file():
        why = f"no PX4 start-up scripts at {etc}/init.d-posix/rcS (beside the binary {binary})"
    return why


def require_px4() -> tuple[Path, Path]:
    """The PX4 SITL binary and its etc/ folder; skips the test when either is missing."""
    why = px4_missing()
    if why is not None:
        pytest.skip(why)
    binary = binary_path(PX4_ENV, PX4_DEFAULT)
    return binary, binary.parent.parent / "etc"


def make_bin(binary: Path, folder: Path) -> int:
    """Fill `folder` with a link to `binary`, its px4-alias.sh and a px4-NAME link per alias in it (what
    PX4's start-up shell runs). Returns the number of px4-NAME links made."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "px4").symlink_to(binary)
    alias = binary.parent / "px4-alias.sh"
    if not alias.is_file():
        raise SitlError(f"no px4-alias.sh beside the PX4 binary {binary}: its shell commands cannot be made")
    shutil.copyfile(alias, folder / "px4-alias.sh")
    names = _ALIAS.findall(alias.read_text())
    for name in names:
        (folder / f"px4-{name}").symlink_to("px4")
    return len(names)


def instance_busy(instance: int) -> str | None:
    """Why PX4 instance number `instance` cannot be used now (None when it can)."""
    for port in (18570 + instance, 14580 + instance):
        if udp_bound(port):
            return f"UDP {port} is bound"
    lock = lock_file(instance)
    if lock.exists():
        try:
            with open(lock, "rb") as f:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(f, fcntl.LOCK_UN)
        except BlockingIOError:
            return f"{lock} is held by a running PX4"
        except OSError as exc:
            return f"{lock} cannot be checked ({exc.strerror})"
    return None


def free_px4_instances(count: int) -> list[int]:
    """`count` instance numbers of PX4_INSTANCES that no running PX4 uses."""
    busy = {n: why for n in PX4_INSTANCES if (why := instance_busy(n))}
    free = [n for n in PX4_INSTANCES if n not in busy]
    if len(free) < count:
        reasons = "; ".join(f"{n}: {why}" for n, why in busy.items())
        raise SitlError(f"{count} PX4 SITL instances wanted but only {free} are free ({reasons})")
    return free[:count]


@dataclass
class PX4Sitl:
    """One running PX4 SITL instance."""

    instance: int
    home: tuple[float, float, float]
    proc: SimProcess

    @property
    def sysid(self) -> int:
        return self.instance + 1

    @property
    def api_port(self) -> int:
        """Where the API (offboard) link sends to: listen here (MAVSDK's connection, or pymavlink's)."""
        return 14540 + self.instance

    @property
    def connection(self) -> str:
        """The mission file's connection string for the API link."""
        return f"udpin:0.0.0.0:{self.api_port}"

    @property
    def mavsdk_url(self) -> str:
        return f"udpin://0.0.0.0:{self.api_port}"

    @property
    def local_ports(self) -> tuple[int, int]:
        """The UDP ports PX4 sends from: the ground-station link (to 14550) and the API link."""
        return (18570 + self.instance, 14580 + self.instance)


def set_param(bin_folder: Path, v: PX4Sitl, name: str, value: float) -> None:
    """`param set NAME VALUE` in a running instance, through PX4's client (px4-param --instance N);
    SitlError when it is not taken."""
    text = repr(int(value)) if float(value).is_integer() else repr(float(value))
    argv = [str(bin_folder / "px4-param"), "--instance", str(v.instance), "set", name, text]
    done = subprocess.run(argv, cwd=v.proc.folder, capture_output=True, text=True, timeout=20)
    if done.returncode != 0:
        raise SitlError(f"PX4 SITL -i {v.instance}: param set {name} {text} failed: {done.stdout}{done.stderr}")


def _started(proc: SimProcess) -> bool:
    return "Startup script returned successfully" in proc.console()


@contextlib.contextmanager
def px4_sitl(
    count: int = 1,
    *,
    homes: Sequence[tuple[float, float, float]] | None = None,
    instances: Sequence[int] | None = None,
    timeout: float = 30.0,
    speed: float = 1.0,
    params: Mapping[str, float] | None = None,
) -> Iterator[list[PX4Sitl]]:
    """Start `count` PX4 SITL instances (SIH quadrotor) in parallel and yield them once each has run its
    start-up script and bound its MAVLink ports. `speed` runs the simulation that many times faster than
    the wall clock (PX4_SIM_SPEED_FACTOR; PX4's start-up script lengthens its link-loss timeouts by it).
    `params` are set once each has started (`param set` through PX4's own shell client, as a user would in
    its console; e.g. NAV_DLL_ACT 2, the GCS failsafe swarmctl's preflight asks for).
    Every instance is stopped, its folder removed and its /tmp socket and lock removed on the way out,
    whatever happened."""
    binary, etc = require_px4()
    chosen = list(instances) if instances is not None else free_px4_instances(count)
    vehicles: list[PX4Sitl] = []
    try:
        with sim_run("swarmctl-px4-") as (root, procs):
            make_bin(binary, root / "bin")
            for n, home in homes_for(chosen, homes, PX4_HOME):
                env = {**PX4_ENV_VARS, "PX4_HOME_LAT": repr(home[0]), "PX4_HOME_LON": repr(home[1])}
                env["PX4_HOME_ALT"] = repr(home[2])
                if speed != 1.0:
                    env["PX4_SIM_SPEED_FACTOR"] = f"{speed:g}"
                argv = [str(root / "bin" / "px4"), "-d", "-i", str(n), "-w", str(root / f"i{n}"), str(etc)]
                procs.append(SimProcess(f"PX4 SITL -i {n}", argv, root / f"i{n}", env).start())
                vehicles.append(PX4Sitl(n, home, procs[-1]))
            wait_until(
                lambda: all(_started(v.proc) and all(udp_bound(p) for p in v.local_ports) for v in vehicles),
                timeout,
                "PX4 SITL to run its start-up script and bind its MAVLink ports",
                procs,
            )
            for v in vehicles:
                for name, value in (params or {}).items():
                    set_param(root / "bin", v, name, value)
            yield vehicles
    finally:  # after sim_run has stopped them
        for v in vehicles:
            if instance_busy(v.instance) is None:  # nobody holds it now: the files are what ours left
                for leftover in (socket_file(v.instance), lock_file(v.instance)):
                    leftover.unlink(missing_ok=True)
