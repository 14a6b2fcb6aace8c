"""Small, pure, firmware-neutral conversions shared by the link, the autopilot drivers and the mock:
degE7 angles, flat-earth offsets, MAV_RESULT names, connection strings and signing key files.
Flight modes differ by firmware and live in swarmctl/mavlink/autopilots/descriptions.py.

Nothing here does I/O except `load_signing_key`, which reads one small file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from swarmctl.errors import InputError

# --- angles -----------------------------------------------------------------------------------------

INT32_MAX = 2**31 - 1


def to_deg_e7(deg: float) -> int:
    """Degrees to MAVLink's int32 degE7, rounded to the nearest unit (about 1.1 cm)."""
    if not math.isfinite(deg) or abs(deg) > 180.0:
        raise ValueError(f"angle {deg!r} is not a latitude/longitude in degrees")
    return int(round(deg * 1e7))


def from_deg_e7(value: int) -> float:
    return value / 1e7


# --- local flat-earth offsets (small distances, good to centimetres over a few km) -----------------

EARTH_RADIUS_M = 6378137.0


def offset_m(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    """The point north_m / east_m metres from (lat, lon)."""
    dlat = math.degrees(north_m / EARTH_RADIUS_M)
    dlon = math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat))))
    return lat + dlat, lon + dlon


def ne_m(lat0: float, lon0: float, lat1: float, lon1: float) -> tuple[float, float]:
    """North and east metres from point 0 to point 1 (inverse of `offset_m` at point 0)."""
    north = math.radians(lat1 - lat0) * EARTH_RADIUS_M
    east = math.radians(lon1 - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return north, east


def distance_m(lat0: float, lon0: float, lat1: float, lon1: float) -> float:
    n, e = ne_m(lat0, lon0, lat1, lon1)
    return math.hypot(n, e)


# --- MAV_RESULT names ---------------------------------------------------------------------------------

MAV_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}

# --- connection strings -------------------------------------------------------------------------------

CONNECTION_HELP = (
    "use udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial device "
    "DEVICE:BAUD (e.g. udpin:0.0.0.0:14550, /dev/ttyUSB0:57600)"
)


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string. kind is udpin, udpout, tcp or serial."""

    kind: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"{self.device}:{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"

    def mavsdk_url(self) -> str:
        """The same endpoint in MAVSDK's URL syntax."""
        if self.kind == "serial":
            return f"serial://{self.device}:{self.baud}"
        scheme = {"udpin": "udpin", "udpout": "udpout", "tcp": "tcpout"}[self.kind]
        return f"{scheme}://{self.host}:{self.port}"


_HOSTPORT = re.compile(r"^(?P<host>[A-Za-z0-9_.\-]+):(?P<port>[^:]*)$")


def parse_connection(text: str, field: str = "connection") -> Endpoint:
    """Parse a MAVProxy/pymavlink-style connection string, or raise InputError naming the field."""
    s = (text or "").strip()

    def bad(why: str) -> InputError:
        return InputError(f"{field} {text!r}: {why}; {CONNECTION_HELP}")

    if not s:
        raise bad("empty")
    scheme, sep, rest = s.partition(":")
    scheme_l = scheme.lower()
    if sep and scheme_l in ("udpin", "udpout", "udp", "tcp"):
        if rest.startswith("//"):
            rest = rest[2:]
        m = _HOSTPORT.match(rest)
        if not m:
            raise bad("expected HOST:PORT after the scheme")
        port_text = m.group("port")
        kind = "udpin" if scheme_l == "udp" else scheme_l
        lowest = 0 if kind == "udpin" else 1  # udpin port 0: any free port (tests)
        if not port_text.isdigit() or not lowest <= int(port_text) <= 65535:
            raise bad(f"port {port_text!r} is not a number from 1 to 65535")
        return Endpoint(kind=kind, host=m.group("host"), port=int(port_text))
    if s.startswith("/") or re.match(r"^COM\d+", s, re.IGNORECASE):
        device, sep, baud_text = s.rpartition(":")
        if not sep:
            device, baud_text = s, "57600"
        if not baud_text.isdigit() or int(baud_text) <= 0:
            raise bad(f"baud rate {baud_text!r} is not a positive number")
        return Endpoint(kind="serial", device=device, baud=int(baud_text))
    raise bad(f"unknown scheme {scheme!r}")


# --- signing keys ----------------------------------------------------------------------------------------


def load_signing_key(path: str | Path, field: str = "--signing-key") -> bytes:
    """A MAVLink 2 signing key: a file holding 32 raw bytes or 64 hex digits."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(
            f"{field} {str(p)!r}: cannot read the key file ({exc.strerror}); "
            "give a file with 32 raw bytes or 64 hex digits"
        ) from None
    if len(data) == 32:
        return data
    text = data.decode("ascii", errors="replace").strip()
    if re.fullmatch(r"[0-9A-Fa-f]{64}", text):
        return bytes.fromhex(text)
    raise InputError(
        f"{field} {str(p)!r}: a signing key is 32 raw bytes or 64 hex digits, "
        f"this file has {len(data)} bytes; create one with "
        "`head -c 32 /dev/urandom > KEYFILE`"
    )
