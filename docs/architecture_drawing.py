"""The drawing of the packages in docs/architecture.md, made from the code: which of our packages
imports which, read from src/quadpilot with `ast` (nothing is imported). The drawing is a Mermaid
graph (GitHub draws it) between the markers `<!-- drawing -->` and `<!-- /drawing -->`.

    python docs/architecture_drawing.py          # rewrite the drawing in docs/architecture.md
    python docs/architecture_drawing.py --check  # exit 1 if the drawing is not the code's

tests/docs/test_architecture_drawing.py runs the check."""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "quadpilot"
DOC = ROOT / "docs" / "architecture.md"
BEGIN, END = "<!-- drawing: made by docs/architecture_drawing.py from the code -->", "<!-- /drawing -->"


def package_of(path: Path, src: Path = SRC) -> str:
    rel = path.relative_to(src)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def imported_packages(path: Path, src: Path = SRC) -> set[str]:
    """Our top-level packages that `path` imports (absolute and relative imports)."""
    rel = path.relative_to(src)
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                module = node.module or ""
            else:  # relative: resolve against the file's package
                base = ["quadpilot", *rel.parts[:-1]][: len(rel.parts) - node.level + 1]
                module = ".".join([*base, *([node.module] if node.module else [])])
            # each name imported: `from quadpilot import console` imports the package console
            names = [f"{module}.{a.name}" for a in node.names]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "quadpilot" and len(parts) > 1:
                out.add(parts[1])
    return out


def package_graph(src: Path = SRC) -> dict[str, set[str]]:
    """{package: the other packages its files import}, for every package and top-level module."""
    graph: dict[str, set[str]] = {}
    for path in sorted(src.rglob("*.py")):
        if path.parent == src and path.name == "__init__.py":
            continue
        pkg = package_of(path, src)
        graph.setdefault(pkg, set()).update(imported_packages(path, src) - {pkg})
    return graph


def drawing(graph: dict[str, set[str]]) -> str:
    lines = ["```mermaid", "graph BT"]
    for pkg in sorted(graph):
        lines += [f"    {pkg} --> {target}" for target in sorted(graph[pkg])] or [f"    {pkg}"]
    return "\n".join([*lines, "```"])


def with_drawing(doc: str, graph: dict[str, set[str]]) -> str:
    head, rest = doc.split(BEGIN, 1)
    return f"{head}{BEGIN}\n{drawing(graph)}\n{END}{rest.split(END, 1)[1]}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="exit 1 if the drawing differs from the code")
    args = p.parse_args(argv)
    doc = DOC.read_text(encoding="utf-8")
    new = with_drawing(doc, package_graph())
    if args.check:
        if new != doc:
            print("docs/architecture.md: the drawing is not the code's; run python docs/architecture_drawing.py")
            return 1
        return 0
    DOC.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
