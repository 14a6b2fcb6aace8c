"""How much of the package's typing is given up: the `Any` names and the `# type: ignore` comments in
swarmctl/ (`make test` prints them beside the type check; tests/test_types.py caps both).

`Any` is counted where it is code (an annotation, an import, a cast), not in comments or strings;
`type: ignore` where it is a comment. Usage: python tools/type_counts.py [PACKAGE_DIR]
"""

from __future__ import annotations

import io
import sys
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "swarmctl"


def file_counts(source: bytes) -> tuple[int, int]:
    """(`Any` names, `type: ignore` comments) in one Python source."""
    anys = ignores = 0
    for tok in tokenize.tokenize(io.BytesIO(source).readline):
        if tok.type == tokenize.NAME and tok.string == "Any":
            anys += 1
        elif tok.type == tokenize.COMMENT and "type: ignore" in tok.string:
            ignores += 1
    return anys, ignores


def counts(package: Path = PACKAGE) -> dict[str, int]:
    """{"Any": ..., "type: ignore": ...} over every .py file under `package`."""
    anys = ignores = 0
    for path in sorted(package.rglob("*.py")):
        a, i = file_counts(path.read_bytes())
        anys, ignores = anys + a, ignores + i
    return {"Any": anys, "type: ignore": ignores}


def main(argv: list[str]) -> int:
    package = Path(argv[1]) if len(argv) > 1 else PACKAGE
    c = counts(package)
    print(f"typing of {package.name}/: {c['Any']} Any, {c['type: ignore']} type: ignore (capped: tests/test_types.py)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
