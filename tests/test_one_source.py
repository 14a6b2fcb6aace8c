"""Each setting and limit is written once: the options made from a config dataclass's fields take the
dataclass's defaults (swarmctl.cli_options.options_from), and no module-level constant is typed again
in another module."""

from __future__ import annotations

import ast
from pathlib import Path

import click
from click.testing import CliRunner

import swarmctl
from swarmctl.bounds import MAX_THREADS
from swarmctl.cli import cli as root
from swarmctl.cli_options import FieldOption, options_from, values_from
from swarmctl.learn.train_config import TrainConfig

# options whose command sets a default of its own, and why
OWN_DEFAULTS = {("train", "--keep-resume"): "None: on with --curriculum or --resume, else off"}
# constants of one name and value in two modules that mean different things
DIFFERENT_MEANINGS = {"SMALL": "world.draws: draws on the Python path; world.beliefs: deciders x vehicles"}


def commands(group: click.Group, path: list[str]):
    """Every command under `group`, with its path (as tests/test_cli.py walks them)."""
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            yield from commands(command, [*path, name])
        else:
            yield [*path, name], command


def test_every_option_made_from_a_dataclass_field_has_the_dataclass_default():
    made, own, wrong = 0, {}, []
    for path, command in commands(root, []):
        where = " ".join(path)
        for param in command.params:
            if not isinstance(param, FieldOption):
                continue
            made += 1
            name = f"{param.config.__name__}.{'/'.join(param.fields)}"
            if param.own_default:
                own[(where, param.opts[0])] = param.default
                continue
            if param.default != param.field_default() or type(param.default) is not type(param.field_default()):
                wrong.append(f"{where} {param.opts[0]}: default {param.default!r}, {name} {param.field_default()!r}")
            default = param.field_default()
            for value in default if param.nargs == 2 else [default]:
                if not param.is_flag and value is not None:  # the default is a value the option accepts
                    assert param.type.convert(value, param, None) == value, f"{where} {param.opts[0]}"
    assert wrong == []
    assert set(own) == set(OWN_DEFAULTS)
    assert made >= 40  # the walk reached eval's and train's options


def test_no_hand_written_option_repeats_a_field_of_the_dataclass_its_command_uses():
    repeated = []
    for path, command in commands(root, []):
        made = [p for p in command.params if isinstance(p, FieldOption)]
        fields = {name for p in made for name in p.config.__dataclass_fields__}
        for param in command.params:
            if not isinstance(param, FieldOption) and param.name in fields:
                repeated.append(f"{' '.join(path)} {param.opts[0]}")
    assert repeated == []


def test_every_threads_option_has_the_same_limit():
    limits = {
        " ".join(path): param.type.max
        for path, command in commands(root, [])
        for param in command.params
        if param.name == "threads"
    }
    assert len(limits) >= 3 and set(limits.values()) == {MAX_THREADS}


def test_options_reach_the_fields_they_are_made_from():
    fields = ("temperature_start", "double", "parallel_envs", "curriculum")
    seen = {}

    @click.command()
    @options_from(TrainConfig, fields)
    def command(**kwargs):
        seen.update(values_from(TrainConfig, kwargs, fields))
        assert kwargs == {}

    runner = CliRunner()
    assert runner.invoke(command, []).exit_code == 0
    assert TrainConfig(**seen) == TrainConfig()
    args = ["--temperature", "2", "0.5", "--plain-target", "--parallel", "3", "--curriculum", "smoke"]
    assert runner.invoke(command, args).exit_code == 0
    assert seen == dict(temperature_start=2.0, temperature_end=0.5, double=False, parallel_envs=3, curriculum="smoke")


def module_constants() -> dict[str, dict[str, object]]:
    """{NAME: {module: value}} of the module-level UPPER_CASE names of swarmctl assigned a literal."""
    found: dict[str, dict[str, object]] = {}
    root_dir = Path(swarmctl.__file__).parent
    for path in sorted(root_dir.rglob("*.py")):
        module = ".".join(path.relative_to(root_dir.parent).with_suffix("").parts)
        for node in ast.parse(path.read_text()).body:
            if not isinstance(node, ast.Assign | ast.AnnAssign) or node.value is None:
                continue
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                names = target.elts if isinstance(target, ast.Tuple) else [target]
                try:
                    value = ast.literal_eval(node.value)
                except ValueError:
                    continue  # not a literal (an alias, an expression)
                values = value if isinstance(target, ast.Tuple) else [value]
                for name, v in zip(names, values):
                    if isinstance(name, ast.Name) and name.id.lstrip("_").isupper():
                        found.setdefault(name.id, {})[module] = v
    return found


def test_no_constant_is_typed_twice():
    constants = module_constants()
    twice = {
        name: where
        for name, where in constants.items()
        if len(where) > 1 and len({repr(v) for v in where.values()}) == 1 and name not in DIFFERENT_MEANINGS
    }
    assert twice == {}
    for name in ("MAX_GRID_SIDE", "MAX_CELL_M", "AIRBORNE_M", "RESUME_ABOVE_M", "LOST_AFTER_S", "CIRCLE_SEGMENTS"):
        assert len(constants[name]) == 1, name
    for gone in ("MAX_MAP", "MAX_CELL_SIZE", "FINISH_RULES", "_CHUNK_CELLS"):  # the copies these replace
        assert gone not in constants
    # one threshold, two names: the odometer's and the rejoin's differ on purpose (mavlink.limits)
    assert constants["AIRBORNE_M"] == {"swarmctl.mavlink.limits": 0.5}
    assert constants["RESUME_ABOVE_M"] == {"swarmctl.mavlink.limits": 1.0}
