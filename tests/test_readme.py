"""README.md and docs/ARCHITECTURE.md, held to what they say.

- Every command in the README's ```sh blocks runs as written, from a folder laid out like the
  repository root (its inputs linked in, its outputs in a temporary folder). A command whose comment
  starts with `# long` (training, the demo, `make test`, anything that needs vehicles) is not run: its
  options must be in its `--help`, the repository paths it names must exist, and a `make` target must
  be in the Makefile.
- The README stays a five-minute read: at most 200 lines.
- The README's links point at files that exist, and its headline table is the JSON it names.
- Every `swarmctl/...py` path, module and dotted name (`rounds.search`, `FieldPolicy.decide`) that
  docs/ARCHITECTURE.md mentions exists.
"""

from __future__ import annotations

import ast
import json
import math
import os
import re
import shlex
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"
PACKAGE = ROOT / "swarmctl"
MAX_LINES = 200
LONG = "long"  # the marker: a trailing `# long...` comment
INPUTS = ("missions", "models", "results", "tests", "tools")  # what the README's commands read, linked in
FILE_TYPES = {"py", "md", "json", "jsonl", "npz", "pt", "plan", "tlog", "toml", "html", "png", "geojson", "kml"}
PLANNERS = ROOT / "results" / "planners" / "61206" / "chicago"  # the headline table's JSON


def readme_commands() -> list[tuple[str, bool]]:
    """(command, long) for every command of the README's ```sh blocks, continuation lines joined."""
    commands = []
    for block in re.findall(r"^```sh\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.M | re.S):
        for line in re.sub(r"\\\n\s*", "", block).splitlines():
            command, _, comment = line.partition(" #")  # a comment starts at the first " #"
            if command.strip():
                commands.append((command.strip(), comment.strip().startswith(LONG)))
    return commands


def env() -> dict[str, str]:
    """This interpreter's environment, its scripts (swarmctl, python) first on the PATH."""
    bin_dir = str(Path(sys.executable).parent)
    return {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""), "MPLBACKEND": "Agg"}


@cache
def help_text(program: tuple[str, ...]) -> str:
    """The --help of a command: `swarmctl SUB` in this process (click's runner), `python tools/x.py` run
    from the repository root."""
    if program[0] == "swarmctl":
        from click.testing import CliRunner

        from swarmctl.cli import cli

        result = CliRunner().invoke(cli, [*program[1:], "--help"], prog_name="swarmctl")
        assert result.exit_code == 0, f"{' '.join(program)} --help failed:\n{result.output}"
        return result.output
    done = subprocess.run(
        [*program, "--help"], cwd=ROOT, env=env(), capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, f"{' '.join(program)} --help failed:\n{done.stderr}"
    return done.stdout


def check_long(command: str) -> None:
    """A command the test does not run: its target, options and paths exist."""
    words = shlex.split(command)
    if words[0] == "make":
        makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
        for target in words[1:]:
            assert re.search(rf"^{re.escape(target)}:", makefile, flags=re.M), f"`make {target}`: no such target"
        return
    if words[0] == "swarmctl":
        program = tuple(words[:2])
    elif words[0] == "python" and words[1].startswith("tools/"):
        program = ("python", words[1])
    else:
        raise AssertionError(f"{command!r}: the README's test checks swarmctl, make and python tools/ commands only")
    text = help_text(program)
    for word in words[len(program) :]:
        if word.startswith("--"):
            option = word.split("=")[0]
            assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text), (
                f"{command!r}: {option} is not an option"
            )
        elif word.split("/")[0] in INPUTS + ("docs",):
            assert (ROOT / word).exists(), f"{command!r}: {word} does not exist"


def test_readme_is_a_five_minute_read():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines; move detail to docs/ (at most {MAX_LINES})"


def test_readme_has_commands_to_run_and_the_two_set_up_commands():
    commands = readme_commands()
    assert ("make demo", True) in commands and ("make test", True) in commands
    assert sum(not long for _, long in commands) >= 5
    for sub in ("demo", "plan", "fly", "replay", "eval", "train"):
        assert any(c.startswith(f"swarmctl {sub} ") for c, _ in commands), f"no example of swarmctl {sub}"


def test_long_readme_commands_match_their_help():
    for command, long in readme_commands():
        if long:
            check_long(command)


def test_readme_commands_run_as_written(tmp_path):
    for name in INPUTS:
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    for command, long in readme_commands():
        if long:
            continue
        done = subprocess.run(
            command, shell=True, cwd=tmp_path, env=env(), capture_output=True, text=True, timeout=300, check=False
        )
        assert done.returncode == 0, (
            f"{command!r} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
        )


def linked_files(path: Path) -> list[str]:
    """The relative files a Markdown page links to, anchors dropped."""
    links = re.findall(r"\]\(([^)]+)\)", path.read_text(encoding="utf-8"))
    return [link.split("#")[0] for link in links if not re.match(r"[a-z]+:", link) and not link.startswith("#")]


@pytest.mark.parametrize("page", ["README.md", "docs/guide.md", "docs/vehicles.md", "docs/benchmarks.md"])
def test_links_point_at_files(page):
    path = ROOT / page
    missing = [link for link in linked_files(path) if not (path.parent / link).exists()]
    assert missing == []


def slug(policy: str) -> str:
    """The JSON file name of a policy in results/planners/ (tools/planner_table.py)."""
    return re.sub(r"[^A-Za-z0-9.=-]+", "_", policy)


def test_the_headline_table_is_the_json_it_names():
    text = README.read_text(encoding="utf-8")
    section = text.split("## Headline results", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([^`]+)`[^|]* \| ([\d.]+) ± ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|$", section, flags=re.M)
    assert len(rows) >= 5
    assert "seed 61206" in section and "results/planners/61206/chicago/" in section
    for policy, success, error, steps, ratio in rows:
        path = PLANNERS / f"{slug(policy)}.json"
        assert path.exists(), f"the headline row {policy} has no {path.relative_to(ROOT)}"
        r = json.loads(path.read_text())
        p, n = r["success_rate"], r["episodes"]
        world = r["scenario"]  # the WorldConfig the episodes were played with
        assert (r["seed"], n, r["finish"], world["uavs"], world["targets"], world["steps"]) == (
            61206,
            200,
            "held",
            3,
            3,
            300,
        )
        assert success == f"{p:.3f}" and error == f"{math.sqrt(p * (1 - p) / n):.3f}", policy
        assert steps == f"{r['mean_steps']:.1f}" and ratio == f"{r['duration_ratio_to_oracle']:.2f}", policy


# ----- docs/ARCHITECTURE.md -----------------------------------------------------------------------


@cache
def code_index() -> tuple[dict[str, list[set[str]]], dict[str, set[str]]]:
    """Module stem -> the top-level names of each module so named; class name -> its members."""
    modules: dict[str, list[set[str]]] = {}
    classes: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        names: set[str] = set()
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign | ast.AnnAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names |= {t.id for t in targets if isinstance(t, ast.Name)}
            elif isinstance(node, ast.ImportFrom | ast.Import):
                names |= {(a.asname or a.name).split(".")[0] for a in node.names}
            if isinstance(node, ast.ClassDef):
                members = classes.setdefault(node.name, set())
                for item in node.body:
                    if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef):
                        members.add(item.name)
                    elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                        members.add(item.target.id)
        stem = path.parent.name if path.name == "__init__.py" else path.stem
        modules.setdefault(stem, []).append(names)
    return modules, classes


def resolves(dotted: str) -> bool | None:
    """Whether a dotted name of the code exists: `swarmctl.errors.InputError`, `rounds.search` (module
    stem . name), `FieldPolicy.decide` (class . member); None when it names no module or class here."""
    modules, classes = code_index()
    parts = dotted.split(".")
    if parts[0] == "swarmctl":
        path = ROOT / "swarmctl"
        while len(parts) > 1 and ((path / parts[1]).is_dir() or (path / f"{parts[1]}.py").exists()):
            path, parts = path / parts[1], parts[1:]
        if len(parts) == 1:
            return True
    head, name, *rest = parts
    if head in modules:
        if not any(name in names for names in modules[head]):
            return False
        return not rest or rest[0] in classes.get(name, set())
    if head in classes:
        return name in classes[head]
    return None


def test_architecture_paths_exist():
    text = ARCHITECTURE.read_text(encoding="utf-8")
    paths = set(re.findall(r"swarmctl/[\w/]+\.py", text)) | set(re.findall(r"swarmctl/[\w/]+/", text))
    assert paths, "no paths found"
    assert sorted(p for p in paths if not (ROOT / p).exists()) == []


def test_architecture_names_only_modules_that_exist():
    """Each module a row of the table names (`config.py`, `autopilots/`, `policy/fused.py`) is in that
    package (or a folder of it), or named from swarmctl/."""
    missing = []
    for package, row in re.findall(
        r"^\| `swarmctl/(\w+)/` \| (.*) \|$", ARCHITECTURE.read_text(encoding="utf-8"), re.M
    ):
        for name in re.findall(r"`([\w/]+(?:\.py|/))`", row):
            here = PACKAGE / package
            if not ((here / name).exists() or (PACKAGE / name).exists() or any(here.rglob(name.rstrip("/")))):
                missing.append(f"swarmctl/{package}/: {name}")
    assert missing == []


def test_architecture_dotted_names_exist():
    text = ARCHITECTURE.read_text(encoding="utf-8")
    tokens = set(re.findall(r"`([^`\s]+)`", text)) | set(re.findall(r"\b([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+)\b", text))
    checked, wrong = 0, []
    for token in tokens:
        name = token.split("(")[0]
        if not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", name) or name.rsplit(".", 1)[1] in FILE_TYPES:
            continue
        found = resolves(name)
        checked += found is not None
        if found is False:
            wrong.append(name)
    assert checked >= 10, "the doc names few code objects: is the check still finding them?"
    assert sorted(wrong) == []


def test_architecture_round_uses_what_rounds_calls():
    """The decision round as docs/ARCHITECTURE.md draws it: beliefs, then decide (`FieldPolicy.choose`
    is for tests and callers holding Knowledge only)."""
    rounds = (PACKAGE / "mission" / "rounds.py").read_text(encoding="utf-8")
    text = ARCHITECTURE.read_text(encoding="utf-8")
    assert "self.policy.beliefs(" in rounds and "self.policy.decide(" in rounds
    assert "FieldPolicy.beliefs" in text and "FieldPolicy.decide" in text and "FieldPolicy.choose" not in text


@cache
def defined_names() -> set[str]:
    """Every name the package defines: functions, classes, fields, assigned names and attributes, arguments."""
    names: set[str] = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.arg):
                names.add(node.arg)
            elif isinstance(node, ast.Name | ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.id if isinstance(node, ast.Name) else node.attr)
    return names


def test_architecture_function_names_exist():
    """Each snake_case name the doc mentions (`beliefs_from_knowledge`, `poll_all`) is defined in the code."""
    words = set(re.findall(r"\b([a-z]+(?:_[a-z0-9]+)+)\b(?!\.py)", ARCHITECTURE.read_text(encoding="utf-8")))
    assert len(words) >= 5
    assert sorted(words - defined_names()) == []
