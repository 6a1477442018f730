"""docs/architecture.md's import direction: runtime, simulator and sitl never pull in torch, gymnasium or the
training side; `import quadpilot` alone stays light."""

import subprocess
import sys

import pytest

HEAVY = ("torch", "gymnasium", "stable_baselines3", "quadpilot.train", "quadpilot.export")


@pytest.mark.parametrize(
    "module",
    [
        *("quadpilot", "quadpilot.core", "quadpilot.link", "quadpilot.runtime", "quadpilot.simulator"),
        *("quadpilot.sitl", "quadpilot.viz"),
    ],
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


def test_runtime_loads_and_flies_a_policy_with_torch_unimportable():
    """In a fresh interpreter where `import torch` (and gymnasium) fail, the runtime still loads
    the shipped ONNX file on every backend (the C one where a compiler exists), passes its
    contract check and acts through the safety monitor; the simulator package imports too, and
    nothing of train or export is imported."""
    from quadpilot.runtime.cbackend import find_compiler

    backends = ("onnxruntime", "numpy") + (("c",) if find_compiler() else ())
    code = """
import sys
class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "gymnasium", "stable_baselines3"):
            raise ImportError("refused by the test: " + name)
        return None
sys.meta_path.insert(0, Refuse())
import quadpilot.simulator
from quadpilot.runtime import SafetyMonitor, load_policy
for backend in sys.argv[2:]:
    monitor = SafetyMonitor(load_policy(sys.argv[1], backend))
    motors = monitor.act(monitor.policy.info.golden_obs[0])
    assert motors.shape == (4,) and monitor.source == "policy", (motors, monitor.events)
print(sorted(m for m in sys.modules if m.startswith(("torch", "gymnasium", "quadpilot.train", "quadpilot.export"))))
"""
    import pathlib

    model = pathlib.Path(__file__).parents[1] / "models" / "hover" / "policy.onnx"
    out = subprocess.run([sys.executable, "-c", code, str(model), *backends], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
