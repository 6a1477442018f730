"""DESIGN.md's import direction: runtime and firmware_sim never pull in torch, gymnasium or the
training side; `import quadpilot` alone stays light."""

import subprocess
import sys

import pytest

HEAVY = ("torch", "gymnasium", "stable_baselines3", "quadpilot.train", "quadpilot.export")


@pytest.mark.parametrize(
    "module", ["quadpilot", "quadpilot.core", "quadpilot.link", "quadpilot.runtime", "quadpilot.firmware_sim"]
)
def test_light_packages_do_not_import_heavy_ones(module):
    code = f"import sys, {module}; print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", f"{module} imported {out.stdout.strip()}"


def test_core_imports_nothing_of_ours():
    import ast
    import pathlib

    core = pathlib.Path(__file__).parents[1] / "src" / "quadpilot" / "core"
    for path in core.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else []
            else:
                continue
            for name in names:
                assert not name.startswith("quadpilot"), f"core/{path.name} imports {name}"
