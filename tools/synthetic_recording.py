"""Write a large synthetic recording, to measure `swarmctl replay` on a swarm the demo cannot fly here.

N vehicles search the demo's Chicago grid for S steps, one step per simulated second: each moves to
the free neighbouring cell (or stays) whose sensing disc holds the most cells its knowledge lacks
(ties drawn with the seed), knowledge is shared ideally, targets are hidden as the demo hides them.
The files are written by the real Recorder in the layout a mission leaves: events.jsonl (mission,
state and step lines), knowledge.jsonl (the snapshot writer), grid.npz, truth.json, summary.json and
mission.tlog with what a ground-mode controller of that many vehicles records: per vehicle
HEARTBEAT and SYS_STATUS at 1 Hz, GLOBAL_POSITION_INT at 20 Hz along its path, the controller's
position targets, and the knowledge TUNNEL frames (swarmctl.knowledge.codec: a DELTA per step, the
digest every 5 steps, DETECTIONs) once as sent and once per other vehicle as received.

With `--policy SPEC` a swarmctl policy (frontier, ddql:PATH, ...) decides instead, on the Beliefs
built from the vehicles' Knowledge as the controller builds them, its moves pass the safety guard, and
the recording keeps the decision inputs (inputs.jsonl) and the policy's seed, so `swarmctl replay
--verify` checks it:

    python tools/synthetic_recording.py --uavs 50 --steps 200 --out runs/synthetic-50x200
    swarmctl replay runs/synthetic-50x200 --quiet
    python tools/synthetic_recording.py --policy frontier --out runs/synthetic-frontier
    swarmctl replay runs/synthetic-frontier --verify --quiet
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from swarmctl.geo.grid import GeoGrid  # noqa: E402
from swarmctl.knowledge.codec import KnowledgeCodec  # noqa: E402
from swarmctl.knowledge.model import Detection, Knowledge, disc_cells  # noqa: E402
from swarmctl.mission.decide import Choice, FieldPolicy  # noqa: E402
from swarmctl.mission.recorder import Recorder  # noqa: E402
from swarmctl.replay.truth import write_truth  # noqa: E402
from swarmctl.sim.swarm import hide_targets, start_cells  # noqa: E402
from swarmctl.world.guard import REASONS, guard_moves  # noqa: E402
from swarmctl.world.moves import MOVE_NAMES, MOVES  # noqa: E402
from swarmctl.world.scenario import value_map  # noqa: E402

GRID = Path(__file__).resolve().parents[1] / "missions" / "chicago-loop" / "grid.npz"
T0 = 1_800_000_000.0  # 2027-01-15: a fixed start; the same arguments give the same files (but the snapshots' "t")
MAV = mavlink2


class _Swarm:
    def __init__(self, grid: GeoGrid, uavs: int, seed: int):
        self.grid, self.rng = grid, np.random.default_rng(seed)
        self.starts = start_cells(grid, uavs)
        self.targets = hide_targets(grid, uavs, seed, self.starts)
        w, h = grid.width, grid.height
        self.phi, self.obstacle = value_map(self.targets, w, h), grid.blocked.copy()
        self.cells = [tuple(c) for c in self.starts]
        self.knowledge = [Knowledge(w, h, vehicle_id=i) for i in range(uavs)]
        self.codecs = [KnowledgeCodec(7, w, h, system_id=i + 1) for i in range(uavs)]
        self.target_set = {tuple(int(v) for v in t) for t in self.targets}
        self.hovering: set[int] = set()

    def sense(self, i: int, step: int) -> list[bytes]:
        """Vehicle i senses its disc; returns the TUNNEL frames it sends (delta, detection)."""
        kn, cell = self.knowledge[i], self.cells[i]
        kn.set_position(step, cell, i in self.hovering)
        kn.sense_truth(self.phi, self.obstacle)
        frames = self.codecs[i].frames(kn.take_delta())
        seen = [c for c in map(tuple, disc_cells(cell, self.grid.width, self.grid.height)) if c in self.target_set]
        fresh = [c for c in seen if c not in kn.targets]
        if fresh:
            kn.add_targets(fresh, step)
            frames += self.codecs[i].frames(Detection(i, step, cell, False, np.array(fresh)))
        if step % 5 == i % 5:
            for chunk in self.codecs[i].digest(i, step, cell, i in self.hovering, kn.explored):
                frames += self.codecs[i].frames(chunk)
        return frames

    def share(self) -> None:
        union = self.knowledge[0].copy()
        for kn in self.knowledge[1:]:
            union.merge(kn)
        for kn in self.knowledge:
            kn.merge(union)

    def choose(self, i: int, taken: set) -> int:
        kn, (x, y) = self.knowledge[i], self.cells[i]
        if i in self.hovering:
            return 0
        if (x, y) in kn.targets and (x, y) not in {self.cells[j] for j in self.hovering}:
            self.hovering.add(i)
            return 0
        best, moves = -1, []
        for m, (dx, dy) in enumerate(MOVES):
            c = (x + int(dx), y + int(dy))
            if not self.grid.in_grid(*c) or self.grid.blocked[c] or (m and c in taken):
                continue
            gain = int((~kn.explored[tuple(disc_cells(c, self.grid.width, self.grid.height).T)]).sum())
            gain += 100 * (c in kn.targets)
            if gain > best:
                best, moves = gain, [m]
            elif gain == best:
                moves.append(m)
        return int(self.rng.choice(moves)) if moves else 0

    def decide(self, policy: FieldPolicy, step: int, rec: Recorder, names: list[str]) -> list[tuple]:
        """One round decided by `policy` as the controller decides it: vehicles on a known target no one
        hovers over start hovering, the others decide in one batch, the guard checks every move; the
        round's inputs line is recorded. Returns (vehicle, Choice, guarded move, refusal) per decider."""
        n = len(self.cells)
        for i in range(n):
            if i not in self.hovering and self.cells[i] in self.knowledge[i].targets:
                if self.cells[i] not in {self.cells[j] for j in self.hovering}:
                    self.hovering.add(i)
        deciders = [i for i in range(n) if i not in self.hovering]
        if not deciders:
            return []
        beliefs = policy.beliefs([self.knowledge[i] for i in deciders], step - 1, n)
        chosen = dict(zip(deciders, policy.decide(beliefs)))
        pos = np.array(self.cells, dtype=np.int64)
        want = pos + np.array([MOVES[chosen[i].move if i in chosen else 0] for i in range(n)], dtype=np.int64)
        dest, refused = guard_moves(pos[None], want[None], self.grid.blocked)
        rec.inputs(step, [names[i] for i in deciders], beliefs, [(j, self.cells[j]) for j in sorted(self.hovering)])
        out = []
        for i in deciders:
            guarded = next(m for m, d in enumerate(MOVES) if tuple(pos[i] + d) == tuple(dest[0, i]))
            out.append((i, chosen[i], guarded, REASONS.get(int(refused[0, i]))))
        return out


def _mav(sysid: int, comp: int = 1) -> mavlink2.MAVLink:
    return mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=comp)


def write(out: Path, uavs: int, steps: int, seed: int, policy_spec: str | None = None) -> Path:
    grid = GeoGrid.load(GRID)
    policy = FieldPolicy(policy_spec, seed=seed) if policy_spec else None
    recorded = policy.recorded() if policy else {}
    swarm = _Swarm(grid, uavs, seed)
    out.mkdir(parents=True, exist_ok=True)
    rec = Recorder(out)
    rec.copy_inputs(None, GRID)
    write_truth(out, swarm, seed)
    names = [f"uav{i + 1}" for i in range(uavs)]
    vehicles = [_mav(i + 1) for i in range(uavs)]
    gcs = _mav(255, 190)
    t = T0
    rec.event(
        "mission",
        t=t,
        name="synthetic",
        policy=policy_spec or "greedy-explorer",
        altitude=40.0,
        end_action="rtl",
        grid=[grid.width, grid.height],
        vehicles=names,
        fence=None,
        **recorded,
    )
    for i, n in enumerate(names):
        rec.event("state", t=t, vehicle=n, sysid=i + 1, state="search", cell=list(swarm.cells[i]))
    for i in range(uavs):
        for f in swarm.sense(i, 0):
            for _copy in range(uavs):
                rec.packet(f, t)
    swarm.share()
    found_at: dict = {}
    for step in range(1, steps + 1):
        if policy is None:
            decided = _greedy_round(swarm, uavs)
        else:
            decided = swarm.decide(policy, step, rec, names)
        moves = [(0, swarm.cells[i]) for i in range(uavs)]
        records = []
        for i, ch, g, why in decided:
            moves[i] = (g, (swarm.cells[i][0] + int(MOVES[g][0]), swarm.cells[i][1] + int(MOVES[g][1])))
            record = dict(
                vehicle=names[i],
                sysid=i + 1,
                cell=list(swarm.cells[i]),
                obs=ch.obs_digest,
                q=ch.q,
                move=MOVE_NAMES[ch.move],
                guarded=MOVE_NAMES[g],
                refused=why,
                received=uavs - 1,
            )
            records.append(record | ({"by": ch.by} if ch.by else {}))
        # one simulated second: 20 Hz positions along each move, 1 Hz heartbeat and battery
        lat0, lon0 = grid.cells_to_latlon(*np.array([swarm.cells[i] for i in range(uavs)]).T)
        lat1, lon1 = grid.cells_to_latlon(*np.array([c for _m, c in moves]).T)
        rec.packet(gcs.heartbeat_encode(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(gcs), t)
        for i, (m, _c) in enumerate(moves):
            if m:
                msg = gcs.set_position_target_global_int_encode(
                    0, i + 1, 1, 6, 0xDF8, int(lat1[i] * 1e7), int(lon1[i] * 1e7), 40.0, 0, 0, 0, 0, 0, 0, 0, 0
                )
                rec.packet(msg.pack(gcs), t)
        for k in range(20):
            a = (k + 1) / 20
            for i, mav in enumerate(vehicles):
                lat, lon = lat0[i] + a * (lat1[i] - lat0[i]), lon0[i] + a * (lon1[i] - lon0[i])
                msg = mav.global_position_int_encode(
                    int((t - T0) * 1000) + 50 * k, int(lat * 1e7), int(lon * 1e7), 220_000, 40_000, 0, 0, 0, 0
                )
                rec.packet(msg.pack(mav), t + 0.05 * k)
        for mav in vehicles:
            hb = mav.heartbeat_encode(
                MAV.MAV_TYPE_QUADROTOR,
                MAV.MAV_AUTOPILOT_ARDUPILOTMEGA,
                MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV.MAV_MODE_FLAG_SAFETY_ARMED,
                4,
                4,
            )
            rec.packet(hb.pack(mav), t + 0.5)
            battery = max(0, 100 - int(60 * step / steps))
            status = mav.sys_status_encode(0, 0, 0, 500, 15000, 1000, battery, 0, 0, 0, 0, 0, 0)
            rec.packet(status.pack(mav), t + 0.5)
        t += 1.0
        for i, (_m, c) in enumerate(moves):
            swarm.cells[i] = c
        for i in range(uavs):
            for f in swarm.sense(i, step):
                for _copy in range(uavs):
                    rec.packet(f, t - 0.01)
            for cell, s in swarm.knowledge[i].targets.items():
                if s == step and cell not in found_at:
                    found_at[cell] = step
                    rec.event(
                        "targets",
                        t=t,
                        vehicle=names[i],
                        cells=[list(cell)],
                        step=step,
                        latlon=[list(grid.cell_to_latlon(*cell))],
                    )
        swarm.share()
        others = [
            dict(vehicle=names[i], sysid=i + 1, state="hover", cell=list(swarm.cells[i]), received=0)
            for i in sorted(swarm.hovering)
        ]
        if policy is None:
            records = [r for r in records if int(r["sysid"]) - 1 not in swarm.hovering or r["move"] != "stay"]
        rec.event("step", t=t, step=step, vehicles=records, others=others, decide_ms=1.0)
        rec.knowledge(step, [(n, kn) for n, kn in zip(names, swarm.knowledge)])
    rec.event("end", t=t, outcome="time limit", step=steps)
    summary = dict(
        mission="synthetic",
        policy=policy_spec or "greedy-explorer",
        outcome="time limit",
        steps=steps,
        search_time_s=float(steps),
        time_s=float(steps),
        vehicles=[dict(name=n) for n in names],
        targets_found=[
            dict(cell=list(c), lat=grid.cell_to_latlon(*c)[0], lon=grid.cell_to_latlon(*c)[1], step=s)
            for c, s in sorted(found_at.items())
        ],
    )
    rec.write_summary(summary)
    rec.close()
    return out


def _greedy_round(swarm: _Swarm, uavs: int) -> list[tuple]:
    """The greedy explorer's round: (vehicle, Choice, move, None) for every vehicle, in index order, each
    avoiding the cells the others hold and those the ones before it move to."""
    taken: set = set()
    out = []
    for i in range(uavs):
        m = swarm.choose(i, taken | {swarm.cells[j] for j in range(uavs) if j != i})
        taken.add((swarm.cells[i][0] + int(MOVES[m][0]), swarm.cells[i][1] + int(MOVES[m][1])))
        out.append((i, Choice(m), m, None))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--uavs", type=int, default=50)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("runs/synthetic-50x200"))
    p.add_argument("--policy", default=None, help="a swarmctl policy decides (module docstring)")
    args = p.parse_args()
    out = write(args.out, args.uavs, args.steps, args.seed, args.policy)
    sizes = {f.name: f.stat().st_size for f in sorted(out.iterdir()) if f.is_file()}
    print(json.dumps({"folder": str(out), "bytes": sizes}, indent=1))


if __name__ == "__main__":
    main()
