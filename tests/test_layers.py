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


# --- the controller's parts, and no circles -------------------------------------------------------------

BUILDERS = {"swarmctl/mission/cli.py", "swarmctl/mission/service.py"}  # they build the parts
NO_CYCLES = ("mission", "knowledge", "mavlink", "geo")


def annotated_controller(path: Path) -> list[str]:
    """Parameters annotated `Controller` (or "Controller", or a union or subscript naming it)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        args = node.args
        for arg in [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]:
            if arg is None or arg.annotation is None:
                continue
            text = ast.unparse(arg.annotation)
            if re.search(r"\bController\b", text):
                found.append(f"{path}:{arg.lineno} {getattr(node, 'name', 'lambda')}({arg.arg})")
    return found


def test_no_function_takes_the_whole_controller():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if str(path.relative_to(ROOT)) not in BUILDERS:
            found += annotated_controller(path)
    assert found == []


def test_the_check_finds_a_controller_parameter(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f(c: 'Controller', n: int) -> None: ...\nasync def g(*, x: Controller | None): ...\n")
    assert len(annotated_controller(bad)) == 2


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_imports(path: Path, modules: set[str]) -> set[str]:
    """The modules of `modules` that `path` imports anywhere: at the top, in functions, and under
    TYPE_CHECKING (`from a.b import c` counts a.b, and a.b.c where that is a module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        found |= {n for n in names if n in modules}
    return found


def import_cycles(package: str) -> list[list[str]]:
    """The groups of modules of swarmctl.<package> that import each other in a circle (the strongly
    connected components of the import graph with more than one module, or a module importing itself)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    paths = {module_name(p): p for p in sorted((PACKAGE / package).rglob("*.py"))}
    names = sorted(paths)
    index = {n: i for i, n in enumerate(names)}
    rows, cols = [], []
    for n in names:
        for m in module_imports(paths[n], set(names)) - {n}:
            rows.append(index[n])
            cols.append(index[m])
    graph = csr_matrix(([1] * len(rows), (rows, cols)), shape=(len(names), len(names)))
    _, labels = connected_components(graph, directed=True, connection="strong")
    groups: dict[int, list[str]] = {}
    for n, label in zip(names, labels):
        groups.setdefault(int(label), []).append(n)
    return [g for g in groups.values() if len(g) > 1]


def test_no_import_cycles_within_the_core_packages():
    assert {p: import_cycles(p) for p in NO_CYCLES} == {p: [] for p in NO_CYCLES}
