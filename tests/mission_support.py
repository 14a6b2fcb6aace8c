"""Shared set-up for the mission tests: a small real-world grid, a simulated swarm, bounded runs."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from typing import Any

import numpy as np

from swarmctl.geo.grid import GeoGrid
from swarmctl.mission.controller import Controller
from swarmctl.mission.recorder import Recorder

PROJ = "+proj=tmerc +lat_0=41.881895 +lon_0=-87.632384 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs +type=crs"


def small_grid(width: int = 10, height: int = 10, cell: float = 10.0, **kw: Any) -> GeoGrid:
    """A width x height grid of 10 m cells in Chicago with a 2 x 2 block of buildings in the middle
    (`kw`: more GeoGrid fields, e.g. the altitude it was planned for)."""
    blocked = np.zeros((width, height), dtype=bool)
    blocked[width // 2 - 1 : width // 2 + 1, height // 2 - 1 : height // 2 + 1] = True
    return GeoGrid(PROJ, (0.0, 0.0), 0.0, cell, blocked, **kw)


def small_mission(tmp_path: Path, saved_grid: GeoGrid | None = None, **mission: str | None) -> Path:
    """mission.toml in tmp_path flying `saved_grid` (small_grid() by default, saved as grid.npz beside
    it) with one vehicle; `mission` adds, replaces (TOML values as text) or, with None, drops keys."""
    (saved_grid or small_grid()).save(tmp_path / "grid.npz")
    fields = {"name": '"small"', "grid": '"grid.npz"', "policy": '"frontier"', "end_action": '"hover"', **mission}
    body = "[mission]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items() if v is not None)
    body += '[[vehicles]]\nname = "a"\nconnection = "udpin:127.0.0.1:14551"\nsysid = 1\n'
    path = tmp_path / "mission.toml"
    path.write_text(body)
    return path


def fly(
    plan: Any, folder: Path, timeout: float = 150.0, during: Any = None, view: Any = None
) -> tuple[Controller, str]:
    """Run a Controller on a fresh loop (with an overall timeout); `during(controller)` is a coroutine
    run alongside (fault injection), `view` its live view. The recording is closed whatever happens."""
    rec = Recorder(folder)
    controller = Controller(plan, rec, view=view)

    async def main() -> str:
        task = asyncio.ensure_future(controller.run())
        side = asyncio.ensure_future(during(controller)) if during is not None else None
        try:
            return await asyncio.wait_for(asyncio.shield(task), timeout)
        finally:
            if side is not None:
                side.cancel()
                try:
                    await side
                except (asyncio.CancelledError, Exception):
                    pass
            if not task.done():
                task.cancel()
                try:
                    await task
                except (asyncio.CancelledError, Exception):
                    pass

    try:
        outcome = asyncio.run(main())
        rec.write_summary(controller.summary())
    finally:
        rec.close()
    return controller, outcome


async def wait_for(condition: Any, timeout: float, what: str) -> None:
    """Poll condition() on the loop until it holds; AssertionError after timeout seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        if loop.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.05)


def our_threads() -> list[str]:
    return [
        t.name for t in threading.enumerate() if t.name.startswith(("mock-autopilot", "mavlink-rx", "knowledge-radio"))
    ]
