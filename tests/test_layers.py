"""docs/ARCHITECTURE.md's layering, held: a package imports only the packages above it in the table of
"Where each piece lives", except the command-line modules (`*/cli.py`), and every module is named there."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "swarmctl"
ARCHITECTURE = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")


def table_order() -> list[str]:
    """The packages in the order of the table's rows."""
    return re.findall(r"^\| `swarmctl/(\w+)/` \|", ARCHITECTURE, flags=re.MULTILINE)


def swarmctl_imports(path: Path) -> set[str]:
    """The swarmctl packages `path` imports (swarmctl.X.... -> X), at any depth of the module."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        found |= {name.split(".")[1] for name in names if name.startswith("swarmctl.") and name.count(".") >= 1}
    return found


def test_the_table_names_every_package():
    packages = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())
    assert sorted(table_order()) == packages


def test_imports_point_up_the_table_except_in_command_line_modules():
    order = table_order()
    downward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).parts
        if len(parts) < 2 or path.name == "cli.py":
            continue
        below = {p for p in swarmctl_imports(path) if p in order and order.index(p) > order.index(parts[0])}
        downward += [f"{path.relative_to(ROOT)} imports swarmctl.{p}" for p in sorted(below)]
    assert downward == []


def test_every_module_is_named_in_the_architecture():
    unnamed = [
        str(path.relative_to(ROOT))
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "__init__.py" and f"{path.name}`" not in ARCHITECTURE  # `name.py` or `swarmctl/name.py`
    ]
    assert unnamed == []
