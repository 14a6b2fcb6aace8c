"""How the agents of one process share knowledge, and where their TUNNEL frames go.

- Ground mode (the plan flies every vehicle: `swarmctl fly`, `swarmctl demo`): the agents share in
  memory, on one `swarmctl.knowledge.bus.KnowledgeBus` (ideal; the demo and tests may give it the
  simulator's channel model, `MissionPlan.bus_channel`). No hub, no address: `[knowledge] channel` is
  not used. Each agent writes each of its frames once, on its own vehicle's MAVLink link (ArduPilot
  through pymavlink), so the recording holds them and an onboard agent or ground station behind the
  vehicle's routing sees them; never on the other vehicles' links. A PX4 vehicle flown through MAVSDK
  sends them through MAVSDK's MavlinkDirect (from MAVSDK's ids 245/190, unsigned; the payload names
  the sender); that link is not in the tlog, so the recording has its knowledge in the snapshots
  (knowledge.jsonl).
- Onboard mode (`swarmctl agent`: the plan flies some vehicles; the others' agents run elsewhere):
  each agent has a UDP socket that sends to `[knowledge] channel` (a MAVLink router or telemetry mesh
  that forwards to every agent) and reads what it forwards; every datagram in and out is recorded.
- In both modes only the mission's vehicles' messages are merged, checked as swarmctl.knowledge.trust says;
  with the mission's signing key every knowledge frame is signed and only signed ones are read.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from swarmctl.knowledge.bus import KnowledgeBus
from swarmctl.knowledge.exchange import DatagramSocket, KnowledgeExchange
from swarmctl.knowledge.model import Knowledge
from swarmctl.knowledge.stack import KnowledgeStack

if TYPE_CHECKING:
    from swarmctl.mission.agent import Agent
    from swarmctl.mission.plan import MissionPlan
    from swarmctl.mission.recorder import Recorder
    from swarmctl.mission.spec import VehicleSpec


class TapSocket:
    """Wraps a KnowledgeExchange's socket so the recorder sees every datagram in and out."""

    def __init__(self, sock: DatagramSocket, recorder: Recorder):
        self._sock, self._rec = sock, recorder

    def sendto(self, data: bytes, addr: Any) -> int:
        self._rec.datagram(data)
        return self._sock.sendto(data, addr)

    def recvfrom(self, size: int) -> tuple[bytes, Any]:
        data, addr = self._sock.recvfrom(size)
        self._rec.datagram(data)
        return data, addr

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


def make_bus(plan: MissionPlan) -> KnowledgeBus | None:
    """The process's bus in ground mode (None in onboard mode), with the stack that holds every agent's
    knowledge (one row per vehicle of the mission: see swarmctl.knowledge.stack)."""
    if plan.onboard:
        return None
    stack = KnowledgeStack(max(1, len(plan.spec.vehicles)), plan.grid.width, plan.grid.height)
    return KnowledgeBus(plan.bus_channel, seed=plan.seed, stack=stack)


def open_exchange(
    plan: MissionPlan, index: int, spec: VehicleSpec, recorder: Recorder, bus: KnowledgeBus | None
) -> KnowledgeExchange:
    """Vehicle `index`'s exchange: on the bus (ground mode; give it its outlet with `link_outlet`) or on
    a UDP socket to the knowledge channel (onboard mode), recorded."""
    if bus is not None and bus.stack is not None:
        kn = bus.stack.knowledge(index)
    else:
        kn = Knowledge(plan.grid.width, plan.grid.height, vehicle_id=index)
    common: dict[str, Any] = dict(
        system_id=spec.sysid,
        digest_every=plan.spec.knowledge.digest_every,
        push=plan.spec.knowledge.push,
        members=members(plan),
        fov=plan.fov,
        signing_key=plan.signing_key,
    )
    if bus is not None:
        return KnowledgeExchange(kn, plan.spec.mission.id, bus=bus, **common)
    channel = plan.spec.knowledge.channel
    if channel is None:  # make_plan refuses such a plan; a plan changed by hand must not fly mute
        raise ValueError("an onboard plan needs a [knowledge] channel")
    exchange = KnowledgeExchange(kn, plan.spec.mission.id, (channel.host, channel.port), **common)
    assert exchange.sock is not None  # a UDP exchange
    exchange.sock = TapSocket(exchange.sock, recorder)
    return exchange


def members(plan: MissionPlan) -> dict[int, int]:
    """Every vehicle of the mission (those other processes fly included): index -> system id, whose
    knowledge messages alone are merged (swarmctl.knowledge.trust)."""
    return {i: v.sysid for i, v in enumerate(plan.spec.vehicles)}


def link_outlet(agent: Agent):
    """A frame writer onto the agent's own vehicle link (looked up at each frame: the vehicle is
    connected after the agent is made): the driver's `write_frame`, False while it has no link."""

    def write(frame: bytes) -> bool:
        send = getattr(agent.vehicle, "write_frame", None)
        return bool(send(frame)) if send is not None else False

    return write


def describe(plan: MissionPlan) -> list[str]:
    """How knowledge travels and what each vehicle senses, for the plan's description."""
    spec = plan.spec
    if plan.onboard:
        lines = [f"knowledge: over the channel {spec.knowledge.channel}, shared with the agents of the other vehicles"]
    else:
        line = (
            "knowledge: shared in this process (no hub to run); each agent's TUNNEL messages also go out once "
            "on its own vehicle's MAVLink link (PX4 vehicles: through MAVSDK, not in the tlog)"
        )
        if spec.knowledge.channel is not None:
            line += f"; [knowledge] channel {spec.knowledge.channel} is for swarmctl agent, fly does not use it"
        lines = [line]
    kept = [i for i in range(len(spec.vehicles)) if plan.only is None or i in plan.only]
    with_detector = [i for i in kept if i in plan.detectors]
    where = "the footprint round each cell reached is explored from the vehicle's position"
    if not with_detector:
        lines.append(f"sensing: no detector, so this is a coverage search ({where}); no target can be found")
    elif len(with_detector) < len(kept):
        lines.append(
            f"sensing: {where}; {len(with_detector)} of {len(kept)} vehicles have a detector for the targets "
            "(the others search by coverage only)"
        )
    else:
        lines.append(f"sensing: {where}; each vehicle's detector reports the targets it sees there")
    return lines


def detector_text(detector: Any) -> str:
    """A vehicle's detector as the plan's description says it."""
    if detector is None:
        return "no detector"
    return (
        "detector on its MAVLink link"
        if isinstance(detector, str)
        else f"detector at udp:{detector.host}:{detector.port}"
    )
