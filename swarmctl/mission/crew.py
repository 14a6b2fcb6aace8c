"""The agents this process flies, and what they know together: which vehicles are ours, the cells held
(ours, and in onboard mode the other processes' vehicles as the knowledge channel tells), who hovers
on which target, and each agent's transitions, recorded."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from swarmctl.mission.agent import Agent, State

if TYPE_CHECKING:
    from swarmctl.knowledge.model import Position
    from swarmctl.mission.recorder import Recorder

Cell = tuple[int, int]


class Crew:
    """The agents of this process (`agents`, in mission order) among the mission's `vehicles`; `only`:
    the indices this process flies (None: all of them, ground mode)."""

    def __init__(self, vehicles: int, only: list[int] | None, rec: Recorder):
        self.vehicles = vehicles
        self.only = None if only is None else frozenset(only)
        self.rec = rec
        self.agents: list[Agent] = []

    @property
    def onboard(self) -> bool:
        """Some of the mission's vehicles are flown by other processes (`swarmctl agent`)."""
        return self.only is not None

    def ours(self, vehicle_index: int) -> bool:
        """The vehicle (its index in the mission) is flown by this process."""
        return 0 <= vehicle_index < self.vehicles and (self.only is None or vehicle_index in self.only)

    def enter(self, a: Agent, state: State, **extra: Any) -> None:
        """Move an agent to `state` (Agent.enter checks the transition) and record it."""
        if a.enter(state) or extra:
            self.rec.event("state", vehicle=a.name, sysid=a.spec.sysid, state=state, cell=a.cell, **extra)

    def named(self, name: object) -> Agent | None:
        """This process's agent of that name (None: none, or not a name)."""
        return next((a for a in self.agents if isinstance(name, str) and a.name == name), None)

    def held(self, exclude: Agent | None = None) -> set[Cell]:
        """The cells vehicles hold: this process's agents (but `exclude`) and the vehicles of other
        processes known through the knowledge channel."""
        cells = {a.cell for a in self.agents if a is not exclude and a.cell is not None and a.state is not State.FAILED}
        if not self.onboard:  # ground mode: every vehicle is one of this process's agents
            return cells
        for a in self.agents:
            for v, p in a.knowledge.peers.items():
                if not self.ours(v) and p.cell is not None:
                    cells.add(p.cell)
        return cells

    def newest_of_others(self) -> dict[int, Position | None]:
        """Onboard mode: each vehicle flown by another process -> its newest position known to any of
        our agents (None: never heard of)."""
        out: dict[int, Position | None] = {}
        for v in range(self.vehicles):
            if self.ours(v):
                continue
            known = [p for p in (a.knowledge.positions.get(v) for a in self.agents) if p is not None]
            out[v] = max(known, key=lambda p: p.order()) if known else None
        return out

    def others_hovering(self) -> bool:
        """Every vehicle flown by another process is known to hover on a target of its own (one none of
        ours holds). Always true in ground mode."""
        mine = {a.cell for a in self.agents if a.state is State.HOVER}
        return all(p is not None and p.on_target and p.cell not in mine for p in self.newest_of_others().values())

    def held_targets(self) -> set[Cell]:
        """The distinct target cells live vehicles hover on: this process's, and (onboard) the other
        processes' vehicles known to hover on a target."""
        cells = {a.cell for a in self.agents if a.state is State.HOVER and a.cell is not None}
        for p in self.newest_of_others().values():
            if p is not None and p.on_target and p.cell is not None:
                cells.add(p.cell)
        return cells
