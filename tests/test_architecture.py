"""docs/architecture.md's import table is the law: every import between our packages in
src/quadpilot must be one the table allows, and every package must have a row."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
SRC = ROOT / "src" / "quadpilot"


def allowed() -> dict[str, set[str]]:
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = doc.split("<!-- imports", 1)[1].split("<!-- /imports -->", 1)[0]
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = set(re.findall(r"`([a-z_]+)`", cells[2]))
    return rows


def package_of(path: Path) -> str:
    rel = path.relative_to(SRC)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def imports(path: Path) -> set[str]:
    """Our top-level packages that `path` imports (absolute and relative imports)."""
    rel = path.relative_to(SRC)
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                names = [node.module or ""]
            else:  # relative: resolve against the file's package
                base = ["quadpilot", *rel.parts[:-1]][: len(rel.parts) - node.level + 1]
                names = [".".join([*base, *([node.module] if node.module else [])])]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "quadpilot" and len(parts) > 1:
                out.add(parts[1])
    return out


def test_the_table_has_a_row_for_every_package_and_nothing_else():
    packages = {package_of(p) for p in SRC.rglob("*.py") if p.name != "__init__.py" or p.parent != SRC}
    packages.discard("__init__")
    assert set(allowed()) == packages


def test_every_import_between_packages_is_one_the_table_allows():
    rules = allowed()
    broken = []
    for path in sorted(SRC.rglob("*.py")):
        if path.parent == SRC and path.name == "__init__.py":
            continue
        pkg = package_of(path)
        for target in sorted(imports(path) - {pkg}):
            if target not in rules.get(pkg, set()):
                broken.append(f"{path.relative_to(ROOT)} imports quadpilot.{target}")
    assert not broken, "imports docs/architecture.md does not allow:\n" + "\n".join(broken)
