"""docs/airframes.md's RotorPy walkthrough, its simulator script and the node's command together:
the script steps for at least the node's --duration of sim time. A script that stops first closes
the link, and the node, even with a good policy, ends the flight early and exits 1."""

import re
import shlex
import sys
import types
from pathlib import Path

import pytest

DOC = (Path(__file__).parents[2] / "docs" / "airframes.md").read_text(encoding="utf-8")


def _section_blocks(lang: str) -> list[str]:
    section = DOC.split("## 3. Fly it in RotorPy", 1)[1].split("\n## ", 1)[0]
    return re.findall(rf"^```{lang}\n(.*?)^```", section, re.S | re.M)


def simulated_s(script: str, monkeypatch) -> float:
    """Sim time the script steps RotorPy for, run with a stand-in PX4Multirotor that only adds up dt."""
    flown = []

    class PX4Multirotor:
        def __init__(self, params, initial_state, mavlink_url):
            assert mavlink_url.startswith("tcpin:")

        def step(self, state, control, dt):
            flown.append(dt)
            return state

    modules = {
        "rotorpy": types.ModuleType("rotorpy"),
        "rotorpy.vehicles": types.ModuleType("rotorpy.vehicles"),
        "rotorpy.vehicles.px4_multirotor": types.SimpleNamespace(PX4Multirotor=PX4Multirotor),
        "rotorpy.vehicles.px4_sihsim_quadx_params": types.SimpleNamespace(quad_params={}),
    }
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    exec(compile(script, "docs/airframes.md", "exec"), {})
    return sum(flown)


def test_the_simulator_script_steps_at_least_the_nodes_duration(monkeypatch):
    (script,) = _section_blocks("python")
    (commands,) = _section_blocks("bash")
    words = shlex.split(commands.replace("\\\n", " "), comments=True)
    node = words[words.index("--node-only") - 2 :]
    duration = float(node[node.index("--duration") + 1])
    assert simulated_s(script, monkeypatch) >= duration - 1e-9, "the script stops before the node's --duration"


def test_the_stand_in_counts_what_a_short_script_steps(monkeypatch):
    script = "from rotorpy.vehicles.px4_multirotor import PX4Multirotor\nv = PX4Multirotor({}, {}, 'tcpin:x')\n"
    script += "for _ in range(500):\n    v.step(None, None, 0.01)\n"
    assert simulated_s(script, monkeypatch) == pytest.approx(5.0)
