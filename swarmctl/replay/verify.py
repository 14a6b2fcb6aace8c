"""`swarmctl replay RECORDING --verify`: every recorded decision decided again by the recorded policy
on the recorded beliefs.

The policy is rebuilt from the mission line: its spec with its options and its seed, and for ddql the
checkpoint (the path in the spec, or `--model PATH`), whose weights must have the recorded
`weights_sha256`, run on the recorded forward (torch or onnx). Each round's line of inputs.jsonl
(swarmctl.mission.inputs) gives back the Beliefs of the vehicles that searched; the policy decides
for all of them at once, as the controller did, round after round in step order (lawnmower keeps its
lanes and waypoints between rounds as in the mission), and each decision is judged against the
round's step record:

- planners (frontier, la:N, lawnmower, random) and ddql's straggler hand-off to frontier: the move
  must be the recorded one (their tie-breaks are draws keyed by seed, step and vehicle);
- ddql-greedy: the recorded move, or a tie: the recorded move's Q-value is within TIE of the best;
- ddql (softmax): the move drawn again with the recorded key (seed, step, vehicle) must be the
  recorded one, or a tie: both moves' Q-values within TIE of the best, or the draw within the change of
  the cumulative probabilities that a change of the Q-values by TIE can make (exp(2 TIE / tau) - 1,
  at tau 0.1 about 0.002). Where the draw cannot be reproduced, because the recomputed Q-values
  differ from the recorded ones by more than TIE (or none were recorded), the recorded move's
  probability under the model decides: a mismatch below `--min-probability`. A softmax mismatch
  lists both moves' probabilities under the recomputed Q-values;
- ddql: the observation's digest must be the recorded one (else the beliefs were not rebuilt as the
  vehicle had them) and the move must come from the same source (network or frontier);
- the guard is re-applied to the recorded moves (the proposals of the vehicles that searched, the
  cells the others held, the grid's blocked cells, in mission order): the guarded move and the
  refusal must be the recorded ones.

The decision rules (hover, mask, taken targets, the straggler hand-off) are the policy's own and run
again with it.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmctl.errors import InputError
from swarmctl.mission.decide import FieldPolicy, obs_digest
from swarmctl.mission.inputs import InputsDecoder, InputsError
from swarmctl.mission.rounds import move_index
from swarmctl.policy.base import allowed_moves
from swarmctl.policy.ddql import DDQLPolicy, split_options
from swarmctl.policy.draws import SOFTMAX, Draws
from swarmctl.policy.forward import onnx_available
from swarmctl.replay.cli import MIN_PROBABILITY  # the default of --min-probability
from swarmctl.replay.lines import Lines, read_lines
from swarmctl.world.beliefs import Beliefs
from swarmctl.world.guard import REASONS, guard_moves
from swarmctl.world.moves import MOVE_NAMES, MOVES

TIE = 1e-4  # |delta Q| below this between the best moves is a tie


@dataclass
class Mismatch:
    """A recorded decision (or guarded move) the check did not reproduce."""

    step: int
    vehicle: str
    recorded: str
    recomputed: str
    why: str
    probability: float | None = None  # softmax: the recorded move's probability under the model
    kind: str = "decision"  # or "guard"
    recomputed_probability: float | None = None  # softmax: the recomputed move's

    def text(self) -> str:
        what = "guarded move" if self.kind == "guard" else "move"
        p = ""
        if self.probability is not None:
            p = f" (p(recorded) = {self.probability:.3g}"
            again = self.recomputed_probability
            p += f", p(recomputed) = {again:.3g})" if again is not None else ")"
        return (
            f"step {self.step} {self.vehicle}: recorded {what} {self.recorded}, recomputed {self.recomputed}{p}: "
            f"{self.why}"
        )


@dataclass
class Report:
    """What --verify found (the counts are decisions: one per searching vehicle and round)."""

    policy: str
    seed: int
    weights_sha256: str | None
    forward: str | None
    min_probability: float
    rounds: int = 0
    decisions: int = 0  # recorded decisions
    reproduced: int = 0
    ties: int = 0
    probable: int = 0  # softmax draws that could not be reproduced, the recorded move at least min_probability
    mismatches: list[Mismatch] = field(default_factory=list)
    unchecked: Counter = field(default_factory=Counter)  # why -> decisions not checked
    guarded: int = 0  # recorded moves re-guarded
    notes: list[str] = field(default_factory=list)

    @property
    def checked(self) -> int:
        return self.reproduced + self.ties + self.probable + sum(m.kind == "decision" for m in self.mismatches)

    @property
    def nothing_checked(self) -> bool:
        """The recording has decisions and not one could be checked (its inputs are unreadable): no proof."""
        return self.decisions > 0 and self.checked == 0

    @property
    def ok(self) -> bool:
        return not self.mismatches and not self.nothing_checked

    def lines(self) -> list[str]:
        """The report as printed."""
        net = f", weights sha256 {self.weights_sha256[:16]}..., forward {self.forward}" if self.weights_sha256 else ""
        wrong = sum(m.kind == "decision" for m in self.mismatches)
        guard_wrong = len(self.mismatches) - wrong
        out = [
            f"verify: policy {self.policy} (seed {self.seed}{net})",
            f"verify: {self.decisions} decisions in {self.rounds} rounds: {self.checked} checked, {self.reproduced} "
            f"reproduced, {self.ties} ties, {self.probable} by probability (>= {self.min_probability:g}), "
            f"{wrong} mismatches; {self.guarded} moves re-guarded, {guard_wrong} differ",
        ]
        for why, n in sorted(self.unchecked.items()):
            out.append(f"not checked: {n} decisions: {why}")
        out += [f"mismatch: {m.text()}" for m in self.mismatches]
        out += [f"note: {n}" for n in self.notes]
        if self.nothing_checked:
            out.append(f"verify: none of the {self.decisions} decisions could be checked")
        else:
            out.append("verify: every decision reproduced" if self.ok else f"verify: {len(self.mismatches)} mismatches")
        return out

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(checked=self.checked, ok=self.ok, nothing_checked=self.nothing_checked, unchecked=dict(self.unchecked))
        return d


# --- the recorded policy -------------------------------------------------------------------------------
def rebuild_policy(mission: dict, model: Path | None = None) -> FieldPolicy:
    """The policy the mission line names, with its seed; a ddql checkpoint (the spec's, or `model`) must
    have the recorded weights_sha256 and runs on the recorded forward. InputError (one line) otherwise."""
    spec = str(mission["policy"])
    kind, _, rest = spec.partition(":")
    recorded = mission.get("weights_sha256")
    if kind in ("ddql", "ddql-greedy"):
        path, suffix = split_options(rest)
        chosen = Path(model) if model is not None else Path(path)
        if not chosen.is_file():
            where = f"--model {chosen}" if model is not None else f"{chosen}, the checkpoint the recording names,"
            raise InputError(f"{where} is not there; give the checkpoint the mission flew with --model PATH")
        forward = mission.get("forward") or "auto"
        if "onnx" in forward and not onnx_available():
            raise InputError(
                "the recording's network ran on onnxruntime, which is not installed here: pip install 'swarmctl[onnx]'"
            )
        options = "".join(o for o in re.findall(r":[a-z]+=[^:]*", suffix) if not o.startswith(":forward="))
        spec = f"{kind}:{chosen}{options}:forward={forward}"
    elif model is not None:
        raise InputError(f"--model {model}: the recording's policy {spec!r} has no checkpoint; leave --model out")
    try:
        # recordings from before the hover rules were flown with `first` (a spec's own :hover= wins)
        policy = FieldPolicy(spec, seed=int(mission["seed"]), hover=str(mission.get("hover", "first")))
        policy.set_hold(mission.get("hold"))
    except InputError as exc:
        raise InputError(f"cannot verify the recording's policy {mission['policy']!r}: {exc}") from None
    if recorded is not None and policy.weights_sha256 != recorded:
        raise InputError(
            f"{chosen}: weights sha256 {policy.weights_sha256} differs from the recording's {recorded}; "
            "give the checkpoint the mission flew with --model PATH"
        )
    return policy


# --- judging one decision ------------------------------------------------------------------------------
def _probabilities(q: np.ndarray, allowed: np.ndarray, tau: float) -> np.ndarray:
    z = np.where(allowed, np.asarray(q, dtype=np.float64), -np.inf)
    p = np.exp((z - z.max()) / tau)
    return p / p.sum()


@dataclass
class _Network:
    """What the network decided for one decider, with what judging it needs."""

    move: int
    q: np.ndarray
    obs: str
    by: str | None
    allowed: np.ndarray
    draw: float


Verdict = str | tuple[str, float | None]  # "reproduced", "tie", "probable", or (why not, p(recorded))


def judge_network(record: dict, d: _Network, tau: float | None, min_probability: float) -> Verdict:
    """ "reproduced", "tie" or "probable", or (why it is a mismatch, the recorded move's probability)."""
    m_rec = MOVE_NAMES.index(record["move"])
    if record.get("obs") is not None and record["obs"] != d.obs:
        return "the observation differs from the recorded one (the beliefs were not rebuilt as recorded)", None
    if record.get("by") != d.by:
        return f"the move came from {record.get('by') or 'the network'}, now from {d.by or 'the network'}", None
    if d.move == m_rec:
        return "reproduced"
    if d.by is not None:
        return f"the {d.by} planner's move differs", None
    if not d.allowed[m_rec]:
        return "the decision rules (hover, mask) do not allow the recorded move", None
    best = float(d.q[d.allowed].max())
    if best - d.q[m_rec] < TIE and best - d.q[d.move] < TIE:  # both among the best moves
        return "tie"
    if tau is None:
        return f"its Q-value is {best - d.q[m_rec]:.4g} below the best", None
    p = _probabilities(d.q, d.allowed, tau)
    q_rec = record.get("q")
    if q_rec is not None and len(q_rec) == len(d.q):
        diff = float(np.abs(np.asarray(q_rec, dtype=np.float64) - d.q).max())
    else:
        diff = math.inf
    if diff <= TIE:  # the draw is reproduced: the same key on the same Q-values
        total = np.cumsum(p)
        lo, hi, margin = (total[m_rec - 1] if m_rec else 0.0), total[m_rec], math.expm1(2 * TIE / tau)
        if lo - margin <= d.draw <= hi + margin:
            return "tie"
        return f"the draw {d.draw:.4f} with the recorded key picks {MOVE_NAMES[d.move]}", float(p[m_rec])
    if p[m_rec] >= min_probability:
        return "probable"
    why = "no Q-values recorded" if diff == math.inf else f"the Q-values differ from the recorded ones by {diff:.3g}"
    return f"the draw cannot be reproduced ({why}) and the recorded move is below --min-probability", float(p[m_rec])


def _network(policy: DDQLPolicy, beliefs: Beliefs) -> list[_Network]:
    d = policy.decide(beliefs)
    allowed = allowed_moves(beliefs, policy.hover, policy.mask, policy.hold)[0]
    draws = Draws(policy.seed, beliefs).deciders(SOFTMAX)[0]
    return [
        _Network(
            int(d.moves[0, u]),
            d.q[0, u].astype(np.float64),
            obs_digest(d.obs[0, u]),
            "frontier" if d.by_frontier[0, u] else None,
            allowed[u],
            float(draws[u]),
        )
        for u in range(beliefs.deciders)
    ]


# --- the guard -----------------------------------------------------------------------------------------
def reguard(record: dict, held: list[dict], index: dict[str, int], blocked: np.ndarray) -> list[Mismatch]:
    """The guard re-applied to a round's recorded moves; the guarded moves and refusals that differ."""
    if any(r["vehicle"] not in index for r in record["vehicles"]):
        return []  # a vehicle the mission line does not name: its place in the guard's order is unknown
    entries = []
    for r in record["vehicles"]:
        x, y = r["cell"]
        dx, dy = MOVES[MOVE_NAMES.index(r["move"])]
        entries.append((index[r["vehicle"]], (x, y), (x + int(dx), y + int(dy)), r))
    entries += [(h["index"], tuple(h["cell"]), tuple(h["cell"]), None) for h in held if h["index"] >= 0]
    entries.sort(key=lambda e: e[0])
    entries += [(-1, tuple(h["cell"]), tuple(h["cell"]), None) for h in held if h["index"] < 0]
    dest, refused = guard_moves(
        np.array([e[1] for e in entries], dtype=np.int64)[None],
        np.array([e[2] for e in entries], dtype=np.int64)[None],
        blocked,
    )
    out = []
    for (_i, cell, _want, r), to, code in zip(entries, dest[0], refused[0]):
        if r is None:
            continue
        move, why = MOVE_NAMES[move_index(cell, (int(to[0]), int(to[1])))], REASONS.get(int(code))
        if (move, why) != (r["guarded"], r["refused"]):
            recorded = r["guarded"] + (f" (refused: {r['refused']})" if r["refused"] else "")
            again = move + (f" (refused: {why})" if why else "")
            out.append(Mismatch(int(record["step"]), r["vehicle"], recorded, again, "the guard", kind="guard"))
    return out


# --- the whole recording -------------------------------------------------------------------------------
def _mission(events: Lines, folder: Path) -> dict:
    missions = events.of("mission")
    if not missions:
        raise InputError(f"{events.path}: no readable mission line; cannot verify {folder}")
    mission = missions[0]
    if "seed" not in mission:
        raise InputError(
            f"cannot verify {folder}: recorded before swarmctl kept the decision inputs (no policy seed, "
            "no inputs.jsonl); fly the mission again to verify it"
        )
    return mission


def verify(
    folder: str | Path,
    model: Path | None = None,
    min_probability: float = MIN_PROBABILITY,
    progress: Callable[[int], Any] | None = None,
    total: Callable[[int], Any] | None = None,
) -> Report:
    """Check every decision of the recording `folder` (module docstring). InputError (exit 2) when it
    cannot be checked at all; `total(n)` is told the number of rounds, `progress(1)` each round."""
    from swarmctl.geo.grid import GeoGrid

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: --verify needs a recording folder (fly, agent, demo); a .tlog holds no decisions")
    if not (folder / "events.jsonl").is_file():
        raise InputError(f"{folder}: no events.jsonl, so no decisions to verify; give a folder fly, agent, demo wrote")
    events = read_lines(folder / "events.jsonl")
    mission = _mission(events, folder)
    steps: dict[int, dict] = {}
    for e in events.of("step"):
        steps.setdefault(int(e["step"]), e)
    inputs_path = folder / "inputs.jsonl"
    if not inputs_path.is_file() and any(e["vehicles"] for e in steps.values()):
        raise InputError(f"{inputs_path}: not found (the recording's decisions cannot be checked without it)")
    policy = rebuild_policy(mission, model)
    priors = events.of("prior")
    if priors and policy.uses_prior and (priors[0].get("source") != "uniform" or priors[0].get("pod", 1.0) != 1.0):
        raise InputError(
            f"cannot verify {folder}: its planner weighed a prior or a detector that misses (the prior event), "
            "and the recording keeps no per-round density to decide again from; missions flown by ddql, or "
            "with neither, verify"
        )
    report = Report(
        str(mission["policy"]), int(mission["seed"]), policy.weights_sha256, policy.forward, min_probability
    )
    names = list(mission["vehicles"])
    index = {n: i for i, n in enumerate(names)}
    blocked = GeoGrid.load(folder / "grid.npz").blocked if (folder / "grid.npz").is_file() else None
    if blocked is None:
        report.notes.append("no grid.npz: the guard was not re-applied")
    lines = read_lines(inputs_path) if inputs_path.is_file() else None
    rounds: dict[int, dict] = {}
    for e in lines.of("inputs") if lines is not None else []:
        rounds.setdefault(int(e["step"]), e)
    if lines is not None and lines.damage:
        report.notes.append(f"inputs.jsonl: {len(lines.damage)} damaged lines skipped")
    report.rounds = sum(1 for e in steps.values() if e["vehicles"])
    report.decisions = sum(len(e["vehicles"]) for e in steps.values())
    for s, e in steps.items():
        if e["vehicles"] and s not in rounds:
            report.unchecked["no inputs line for the round"] += len(e["vehicles"])
    width, height = mission["grid"]
    decoder = InputsDecoder(width, height, len(names))
    if total is not None:
        total(len(rounds))
    for s in sorted(rounds):
        _round(policy, decoder, rounds[s], steps.get(s), index, blocked, report)
        if progress is not None:
            progress(1)
    return report


def _round(
    policy: FieldPolicy,
    decoder: InputsDecoder,
    line: dict,
    record: dict | None,
    index: dict[str, int],
    blocked: np.ndarray | None,
    report: Report,
) -> None:
    """Decide one round again and judge it against its step record (None: the mission stopped before it
    was written; the round is still decided, for the policy's state)."""
    recorded = {r["vehicle"]: r for r in record["vehicles"]} if record is not None else {}
    unknown = [n for n in line["vehicles"] if n not in index]
    if unknown:
        report.unchecked[f"the inputs name vehicles not in the mission ({', '.join(unknown)})"] += len(recorded)
        return
    try:
        beliefs = decoder.beliefs(line, [index[n] for n in line["vehicles"]], policy.settings)
    except InputsError as exc:
        report.unchecked[f"an inputs line could not be read ({exc})"] += len(recorded)
        return
    policy.start(beliefs)
    inner = policy.policy
    if isinstance(inner, DDQLPolicy):
        decided: list[Any] = _network(inner, beliefs)
        tau = inner.tau
    else:
        decided = [int(m) for m in inner.act(beliefs)[0]]
        tau = None  # (planners' decisions are ints, never a _Network)
    if record is None:
        return
    missing = set(recorded) - set(line["vehicles"])
    if missing:
        report.unchecked["searched but not among the round's inputs"] += len(missing)
    step = int(record["step"])
    for name, d in zip(line["vehicles"], decided):
        r = recorded.get(name)
        if r is None:
            continue
        if isinstance(d, _Network):
            verdict = judge_network(r, d, tau, report.min_probability)
            move = d.move
        else:
            move = d
            verdict = "reproduced" if MOVE_NAMES[move] == r["move"] else ("the planner's move differs", None)
        if verdict == "reproduced":
            report.reproduced += 1
        elif verdict == "tie":
            report.ties += 1
        elif verdict == "probable":
            report.probable += 1
        else:
            assert isinstance(verdict, tuple)  # a mismatch: (why, p)
            why, p = verdict
            wrong = Mismatch(step, name, r["move"], MOVE_NAMES[move], why, p)
            if isinstance(d, _Network) and tau is not None and d.by is None:  # a softmax move
                probs = _probabilities(d.q, d.allowed, tau)
                wrong.probability = float(probs[MOVE_NAMES.index(r["move"])])
                wrong.recomputed_probability = float(probs[move])
            report.mismatches.append(wrong)
    if blocked is not None:
        report.guarded += len(record["vehicles"])
        report.mismatches += reguard(record, line["held"], index, blocked)
