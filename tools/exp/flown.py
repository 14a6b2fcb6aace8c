"""One simulator episode flown through the MAVLink path: mock autopilots over loopback UDP at the
episode's start cells (swarmctl.sim.swarm.SimSwarm), its targets hidden in their detectors, its
obstacles as the grid's blocked cells, and the real controller in ground mode: its agents share
knowledge as TUNNEL frames on its knowledge bus with the channel model (swarmctl.mission.sharing).
The search is stopped after `steps` decision rounds, as the simulator's episode stops at its step
limit.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np

# a transverse Mercator round the Chicago Loop: the mock vehicles fly real latitudes and longitudes
PROJ = "+proj=tmerc +lat_0=41.881895 +lon_0=-87.632384 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs +type=crs"


def fly_episode(params: dict, folder: Path) -> dict:
    """Fly episode `episode` of `seed` (world `world`) with `policy`; returns the outcome, the rounds
    flown, whether it succeeded within `steps` rounds, and the knowledge and MAVLink counters."""
    from swarmctl.geo.grid import GeoGrid
    from swarmctl.mission.controller import Controller
    from swarmctl.mission.recorder import Recorder
    from swarmctl.sim.swarm import SimSwarm
    from swarmctl.world.channel import Channel
    from swarmctl.world.scenario import generate_scenario
    from tools.exp.tasks import world_config

    cfg = world_config(params["world"])
    scenario = generate_scenario(cfg, params["seed"], params["episode"])
    grid = GeoGrid(PROJ, (0.0, 0.0), 0.0, cfg.cell_size, scenario.obstacles)
    channel = Channel(cfg.channel, cfg.cell_size, cfg.loss)
    swarm = SimSwarm(grid, uavs=cfg.uavs, seed=params["seed"], speedup=params["speedup"], channel=channel)
    swarm.starts = [(int(x), int(y)) for x, y in scenario.starts]  # the episode's, not the launch row
    swarm.targets = scenario.targets.copy()
    limit = params["steps"]
    settings = dict(
        end_action="land", time_limit=params["time_limit"], takeoff_at_once=cfg.uavs, end_timeout=60.0, fence=False
    )
    with swarm:
        plan = swarm.plan(params["policy"], **settings)
        rec = Recorder(folder / "flight")
        controller = Controller(plan, rec)

        async def main() -> str:
            task = asyncio.ensure_future(controller.run())
            while not task.done():
                if controller.step >= limit:  # the episode's step limit
                    controller.stop()
                    break
                await asyncio.sleep(0.02)
            return await task

        t0 = time.monotonic()
        try:
            outcome = asyncio.run(main())
            summary = controller.summary()
            bus = controller.bus.counters()
        finally:
            rec.close()
        wall = time.monotonic() - t0
    hovering = {tuple(c) for c in summary["vehicles_on_targets"]}
    success = outcome == "complete" and controller.step <= limit
    return {
        "episode": params["episode"],
        "policy": params["policy"],
        "outcome": outcome,
        "success": bool(success),
        "steps": int(controller.step) if success else limit,
        "rounds": int(controller.step),
        "vehicles_on_targets": len(hovering),
        "targets": int(len(scenario.targets)),
        "targets_found": len(summary["targets_found"]),
        "knowledge_sent": summary["messages"]["knowledge_sent"],
        "knowledge_received": summary["messages"]["knowledge_received"],
        "knowledge_delivered": bus["delivered"],  # frames, sender -> receiver links
        "knowledge_lost": bus["lost"],
        "refused_moves": int(np.sum([v["refused_moves"] for v in summary["vehicles"]])),
        "mission_wall_s": round(wall, 1),
    }
