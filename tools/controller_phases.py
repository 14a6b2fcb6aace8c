"""Where the controller's loop thread spends its CPU during the search, per decision round.

Flies one search as tools/controller_overhead.py does (mock vehicles in a child process, ground mode,
recorded), with the functions named in PHASES wrapped: each call made on the loop thread while the
search runs adds its CPU time (time.thread_time) to its phase. The table gives, per search round, the
CPU time and the number of calls of each phase. Phases nest (the knowledge publish holds its encoding
and its link writes; a drain of the links holds the telemetry listeners), so the times are inclusive
and do not add up to the round; the wrappers themselves cost about a microsecond a call, so the round
measured here is a little slower than controller_overhead's.

    python tools/controller_phases.py [--vehicles 50] [--policy ddql:models/cluster-2uav.pt] [--search 20]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT))

import controller_overhead  # noqa: E402

# (module, attribute path, label): what a round is made of
PHASES = (
    ("swarmctl.mission.decide", "FieldPolicy.beliefs", "beliefs (Knowledge -> Beliefs)"),
    ("swarmctl.mission.decide", "FieldPolicy.decide", "decision (whole)"),
    ("swarmctl.policy.ddql", "observe", "  observations"),
    ("swarmctl.policy.forward", "OnnxForward.__call__", "  forward (onnxruntime)"),
    ("swarmctl.policy.forward", "TorchForward.__call__", "  forward (torch)"),
    ("swarmctl.policy.forward", "OneDnnForward.__call__", "  forward (oneDNN)"),
    ("swarmctl.mission.decide", "obs_digest", "  observation digests"),
    ("swarmctl.mission.rounds", "poll_all", "knowledge poll (bus merge)"),
    ("swarmctl.knowledge.stepping", "_step_arrays", "knowledge step arrays"),
    ("swarmctl.knowledge.exchange", "KnowledgeExchange._publish", "knowledge publish (whole)"),
    ("swarmctl.knowledge.codec", "KnowledgeCodec.encode_parts", "  encoding"),
    ("swarmctl.knowledge.codec", "KnowledgeCodec.frame", "  TUNNEL framing"),
    ("swarmctl.knowledge.bus", "KnowledgeBus.publish", "  bus publish"),
    ("swarmctl.mavlink.transport", "UdpTransport.write", "link writes (knowledge and commands)"),
    ("swarmctl.mavlink.network", "MavlinkLink.send", "MAVLink commands packed and sent"),
    ("swarmctl.mavlink.inbox", "Inbox._drain", "telemetry drains (whole)"),
    ("swarmctl.mavlink.inbox", "Inbox._read_ready", "  reads (recvfrom and parsing)"),
    ("swarmctl.mavlink.network", "parse_bytes", "    parsed (pymavlink)"),
    ("swarmctl.mavlink.network", "MavlinkLink._deliver", "  listeners"),
    ("swarmctl.mavlink.autopilots.ardupilot", "ArduPilotVehicle._on_position", "    position reports"),
    ("swarmctl.mission.detector", "SensorFeed.on_tunnel", "    detector reports"),
    ("swarmctl.knowledge.codec", "KnowledgeCodec.decode", "      decoded"),
    ("swarmctl.mavlink.inbox", "call_batch_listeners", "  recorder tap (received frames)"),
    ("swarmctl.mission.recorder", "Recorder.packet", "recorder: sent frames"),
    ("swarmctl.mission.recorder", "Recorder.events_at_once", "recorder: events.jsonl"),
    ("swarmctl.mission.recorder", "Recorder.inputs", "recorder: inputs.jsonl"),
    ("swarmctl.mission.recorder", "Recorder.knowledge", "recorder: knowledge.jsonl"),
    ("swarmctl.mission.controller", "Controller.summary", "running summary (built)"),
    ("swarmctl.mission.recorder", "Recorder.write_summary", "running summary (written)"),
    ("swarmctl.mission.rounds", "update_states", "state updates"),
    ("swarmctl.mission.watch", "problems", "course checks (watch)"),
    ("swarmctl.mission.flight", "sense", "sensing (reports -> footprint)"),
    ("swarmctl.mavlink.autopilots.ardupilot", "ArduPilotVehicle._keep_telemetry", "telemetry keep-alive checks"),
)


class PhaseClock:
    """Loop-thread CPU per phase, counted only while `on` (the search runs)."""

    def __init__(self) -> None:
        self.on = False
        self.cpu: defaultdict[str, float] = defaultdict(float)
        self.calls: Counter[str] = Counter()
        self._thread = threading.main_thread()

    def wrap(self, owner, name: str, label: str) -> None:
        inner = getattr(owner, name)

        @functools.wraps(inner)
        def timed(*args, **kwargs):
            if not self.on or threading.current_thread() is not self._thread:
                return inner(*args, **kwargs)
            started = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                self.cpu[label] += time.thread_time() - started
                self.calls[label] += 1

        setattr(owner, name, timed)

    def install(self) -> None:
        for module, path, label in PHASES:
            owner = importlib.import_module(module)
            *parents, name = path.split(".")
            for part in parents:
                owner = getattr(owner, part)
            self.wrap(owner, name, label)
        rounds = importlib.import_module("swarmctl.mission.rounds")
        controller = importlib.import_module("swarmctl.mission.controller")
        search = rounds.search

        async def timed_search(c):
            self.on = True
            try:
                return await search(c)
            finally:
                self.on = False

        controller.search = timed_search  # the name the controller calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--policy", default="ddql:models/cluster-2uav.pt")
    ap.add_argument("--search", type=float, default=20.0, help="seconds of search")
    ap.add_argument("--speedup", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.vehicles < 1 or args.search <= 0:
        ap.error("--vehicles must be at least 1 and --search positive")
    clock = PhaseClock()
    clock.install()
    load = os.getloadavg()[0]
    r = controller_overhead.measure(args.vehicles, args.policy, args.search, args.speedup, args.seed, False)
    n = max(r.get("rounds", 0), 1)
    print(
        f"{args.vehicles} vehicles, policy {args.policy}, {r.get('rounds', 0)} search rounds, "
        f"{os.cpu_count()} CPUs, {controller_overhead.cpu_model()}, load {load:.2f} before; "
        f"controller CPU {r.get('cpu_mean', float('nan')):.1f} ms a round (with the wrappers)\n"
    )
    print("| phase (inclusive; indented: part of the one above) | CPU ms a round | calls a round |")
    print("|:---|---:|---:|")
    for _, _, label in PHASES:
        if clock.calls[label]:
            print(f"| {label} | {1000 * clock.cpu[label] / n:.2f} | {clock.calls[label] / n:.1f} |")


if __name__ == "__main__":
    main()
