"""docs/security.md names the test that guards each rule and the function that enforces it: a
renamed or deleted test or function makes this fail, so the threat model cannot drift from the code."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).parents[2]
DOC = (ROOT / "docs" / "security.md").read_text(encoding="utf-8")


def _defined(folder: Path) -> set[str]:
    names = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.ClassDef):
                names.add(node.name)
    return names


def test_every_test_the_threat_model_names_exists():
    files = {"test_model_files", "test_wire_input", "test_cli_input", "test_path_errors", "test_safety_handback"}
    files |= {"test_handback_flights"}
    named = set(re.findall(r"(?<!Raptor::)\b(test_[a-z0-9_]+)\b", DOC)) - files  # Raptor::test_policy is PX4's
    missing = sorted(named - _defined(ROOT / "tests"))
    assert len(named) >= 20 and not missing, f"docs/security.md names tests that do not exist: {missing}"


def test_every_function_the_threat_model_names_exists():
    named = set(re.findall(r"`(?:[a-z_]+\.)*([A-Za-z_][A-Za-z0-9_]*)`", DOC))
    functions = {n for n in named if n.startswith(("check_", "_read_", "saturating", "lock_run_dir", "blind"))}
    missing = sorted(functions - _defined(ROOT / "src" / "quadpilot"))
    assert len(functions) >= 6 and not missing, f"docs/security.md names functions that do not exist: {missing}"
