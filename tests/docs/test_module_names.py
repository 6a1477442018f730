"""The documents name the project's modules by their own names: a code span such as `cgen.x`, the
alias one source file imports a module under (`from quadpilot.ccode import generate as cgen`),
names no module a reader can find."""

import ast
import importlib
import re
import sys
from pathlib import Path

ROOT = Path(__file__).parents[2]
SRC = ROOT / "src" / "quadpilot"
sys.path.insert(0, str(ROOT / "docs"))
from figures import documents  # noqa: E402


def _module_names() -> set[str]:
    return {p.stem for p in SRC.rglob("*.py")} | {p.name for p in SRC.rglob("*") if p.is_dir()}


def _aliases() -> set[str]:
    """Every `import <module> as <alias>` of a quadpilot module whose alias is no module's name, and
    the ccode modules' c-prefixed names (cgen, charness, cbench: how their importers call them)."""
    modules = _module_names()
    found = {"c" + p.stem for p in (SRC / "ccode").glob("*.py") if p.stem != "__init__"}
    for folder in ("src", "benchmarks", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("quadpilot")):
                    found |= {a.asname for a in node.names if a.asname and a.name in modules}
    return found - modules


def _spans(pattern: str):
    for doc in documents():
        text = doc.read_text(encoding="utf-8")
        for m in re.finditer(pattern, text):
            yield f"{doc.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}", m.group(1)


def test_no_document_names_a_module_by_an_import_alias():
    aliases = _aliases()
    assert {"cgen", "charness"} <= aliases  # the check sees the aliases the source uses
    found = [f"{where}: {name}" for where, name in _spans(r"`((?:" + "|".join(sorted(aliases)) + r")\.\w+)")]
    assert not found, "name the module, not its import alias:\n" + "\n".join(found)


def test_every_ccode_name_the_documents_give_exists():
    named = list(_spans(r"`(quadpilot\.ccode\.\w+(?:\.\w+)?)`"))
    missing = []
    for where, name in named:
        module, _, attr = name.rpartition(".")
        try:
            importlib.import_module(name)
        except ImportError:
            if not hasattr(importlib.import_module(module), attr):
                missing.append(f"{where}: {name}")
    assert len(named) >= 5 and not missing, missing
