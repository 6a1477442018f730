"""The airframe set of the side-by-side with RAPTOR (benchmarks/airframes/*.toml): eight or more
vehicle files spanning 30 g to 2.5 kg, each value with its source in a comment, and RotorPy's
airframes exactly as the converter writes them from the installed RotorPy."""

import re
from pathlib import Path

import pytest

from quadpilot.core.rotorpy_vehicle import main
from quadpilot.core.vehicle_file import load_vehicle_file

SET = Path(__file__).parents[2] / "benchmarks" / "airframes"
FILES = sorted(SET.glob("*.toml"))
UNITS_AND_AXES = {"kg", "kg m^2", "m", "s", "rad/s", "N/(rad/s)^2", "N s/m", "right", "forward (FRD)"}
VALUE = re.compile(r"^(?!\[)(\w+)\s*=\s*([^#]+?)\s*(#\s*(.*))?$")


def test_the_set_spans_what_it_must():
    vehicles = [load_vehicle_file(p) for p in FILES]
    assert len(vehicles) >= 8
    masses = [v.mass for v in vehicles]
    assert min(masses) <= 0.03 and max(masses) >= 2.5
    assert any(v.motor_tau >= 0.1 for v in vehicles)  # a heavy slow-motor quadrotor
    assert any(v.thrust_to_weight >= 4.0 for v in vehicles)  # a racer
    assert any(len({round(c, 9) for c in v.hover_commands}) > 1 for v in vehicles)  # an asymmetric frame


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_every_value_says_where_it_comes_from(path):
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        m = VALUE.match(line)
        if m is None or m.group(1) == "name":
            continue
        comment = (m.group(4) or "").strip()
        # a unit alone is not a source: what follows the unit ("kg, ..." or "m, right, ...") must name one
        parts = [s.strip() for s in comment.split(",")]
        source = [s for s in parts if s and s not in UNITS_AND_AXES]
        assert source, f"{path.name}:{n}: {line!r} has no source in its comment"


@pytest.mark.parametrize("path", [p for p in FILES if p.stem.startswith("rotorpy_")], ids=lambda p: p.stem)
def test_rotorpys_airframes_are_what_the_converter_writes_today(path, tmp_path):
    module = "rotorpy.vehicles." + path.stem.removeprefix("rotorpy_") + "_params"
    out = tmp_path / path.name
    assert main([module, "--name", path.stem, "-o", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == path.read_text(encoding="utf-8")
