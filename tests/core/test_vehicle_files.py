"""Vehicle files (core.vehicle_file): the shipped presets read back to today's presets field by
field, every bad file is refused with one line naming the file and the key, the quad-X layout check,
and the writer/reader round trip."""

import dataclasses
import math
import re

import pytest

from quadpilot.core import dynamics
from quadpilot.core.params import PRESETS, VehicleParams
from quadpilot.core.vehicle_file import (
    QUAD_X,
    VEHICLES_DIR,
    UnknownVehicleError,
    VehicleFileError,
    load_vehicle_file,
    parse_vehicle,
    resolve_vehicle,
    shipped_names,
    vehicle_to_toml,
)

HEAVY = """
name = "heavy"
mass = 1.2
ixx = 0.004
iyy = 0.004
izz = 0.007
k_thrust = 8.9e-7
k_torque = 7.387e-9
omega_max = 2400.0
motor_tau = 0.02
drag = [0.1, 0.1, 0.1]
[[rotor]]
x = 0.1
y = 0.1
spin = "ccw"
[[rotor]]
x = -0.1
y = -0.1
spin = "ccw"
[[rotor]]
x = 0.1
y = -0.1
spin = "cw"
[[rotor]]
x = -0.1
y = 0.1
spin = "cw"
"""


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_shipped_files_equal_the_presets_field_by_field(name):
    v = resolve_vehicle(name)
    want = PRESETS[name]
    for f in dataclasses.fields(VehicleParams):
        got, exp = getattr(v, f.name), getattr(want, f.name)
        assert type(got) is type(exp) and got == exp, (name, f.name, got, exp)


def test_every_preset_is_shipped_and_every_shipped_file_is_named_after_its_vehicle():
    assert shipped_names() == sorted(PRESETS)
    for path in VEHICLES_DIR.glob("*.toml"):
        assert load_vehicle_file(path).name == path.stem


def test_every_number_in_a_shipped_file_carries_a_comment():
    for path in VEHICLES_DIR.glob("*.toml"):
        for line in path.read_text(encoding="utf-8").splitlines():
            if re.match(r"\s*[a-z_]+\s*=\s*[-0-9\[]", line):
                assert "#" in line and len(line.split("#", 1)[1].strip()) > 3, (path.name, line)


def test_a_user_file_maps_onto_vehicle_params():
    v = parse_vehicle(HEAVY.encode(), "heavy.toml")
    assert v.name == "heavy" and v.mass == 1.2 and (v.ixx, v.iyy, v.izz) == (0.004, 0.004, 0.007)
    assert v.k_f == 8.9e-7 and v.k_m == pytest.approx(7.387e-9 / 8.9e-7, rel=1e-12)
    assert v.arm == pytest.approx(0.1 * math.sqrt(2), rel=1e-12)
    assert (v.omega_max, v.motor_tau, v.drag, v.gravity) == (2400.0, 0.02, 0.1, 9.81)


def test_the_accepted_layout_is_the_one_the_dynamics_model():
    """The file's order and spins are `core.dynamics.MOTOR_LAYOUT` (FLU there, FRD in the file)."""
    for (sx, sy, spin), (x, y, s) in zip(QUAD_X, dynamics.MOTOR_LAYOUT.values(), strict=True):
        assert (sx, sy, spin) == (x, -y, "ccw" if s > 0 else "cw")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_written_file_reads_back_bit_for_bit(name, tmp_path):
    for v in (PRESETS[name], dataclasses.replace(PRESETS[name], name="x1", mass=0.9, motor_tau=0.03, drag=0.2)):
        path = tmp_path / "v.toml"
        path.write_text(vehicle_to_toml(v), encoding="utf-8")
        assert load_vehicle_file(path) == v


def _variant(**edits) -> str:
    """HEAVY with top-level keys replaced (value None: removed), as TOML text."""
    lines = HEAVY.strip().splitlines()
    head, rotors = lines[: lines.index("[[rotor]]")], lines[lines.index("[[rotor]]") :]
    out = [ln for ln in head if ln.split("=")[0].strip() not in edits]
    out += [f"{k} = {v}" for k, v in edits.items() if v is not None]
    return "\n".join(out + rotors) + "\n"


BAD = {
    # case: (file text, key named in the message, words of the reason)
    "missing mass": (_variant(mass=None), "mass", "missing"),
    "mass a string": (_variant(mass='"heavy"'), "mass", "expected a number"),
    "mass a boolean": (_variant(mass="true"), "mass", "expected a number"),
    "negative mass": (_variant(mass="-1.0"), "mass", "> 0"),
    "zero inertia": (_variant(iyy="0.0"), "iyy", "> 0"),
    "infinite inertia": (_variant(izz="inf"), "izz", "finite"),
    "nan thrust": (_variant(k_thrust="nan"), "k_thrust", "finite"),
    "negative lag": (_variant(motor_tau="-0.1"), "motor_tau", ">= 0"),
    "idle speed": (_variant(omega_min="100.0"), "omega_min", "only 0"),
    "anisotropic drag": (_variant(drag="[0.1, 0.2, 0.1]"), "drag", "equal"),
    "drag of two": (_variant(drag="[0.1, 0.1]"), "drag", "three"),
    "unknown key": (_variant(arm="0.1"), "arm", "unknown key"),
    "bad name": (_variant(name='"two words"'), "name", "letters"),
    "name a number": (_variant(name="3"), "name", "letters"),
    "no rotor": (_variant().split("[[rotor]]")[0], "rotor", "missing"),
    "three rotors": ("[[rotor]]".join(_variant().split("[[rotor]]")[:4]), "rotor", "quad-X"),
    "rotor a number": (_variant().split("[[rotor]]")[0] + "rotor = 4\n", "rotor", "[[rotor]] tables"),
    "rotor unknown key": (_variant().replace('spin = "cw"', 'spin = "cw"\nz = 0.0', 1), "rotor[3].z", "unknown"),
    "rotor without spin": (_variant().replace('spin = "cw"\n', "", 1), "rotor[3].spin", "missing"),
    "rotor bad spin": (_variant().replace('"cw"', '"clockwise"', 1), "rotor[3].spin", '"cw" or "ccw"'),
    "rotor x a string": (_variant().replace("x = 0.1", 'x = "front"', 1), "rotor[1].x", "expected a number"),
    "swapped spins": (
        _variant().replace('"ccw"', '"xx"').replace('"cw"', '"ccw"').replace('"xx"', '"cw"'),
        "rotor[1]",
        "quad-X",
    ),
    "other output order": (_variant().replace("x = 0.1\ny = 0.1", "x = 0.1\ny = -0.2", 1), "rotor[1]", "quad-X"),
    "not a square": (_variant().replace("x = -0.1\ny = -0.1", "x = -0.12\ny = -0.1", 1), "rotor[2]", "quad-X"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_file_is_refused_with_one_line_naming_file_and_key(case, tmp_path):
    text, key, reason = BAD[case]
    path = tmp_path / "bad_vehicle.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(VehicleFileError) as e:
        load_vehicle_file(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: {key}: "), msg
    assert reason in msg, msg
    assert isinstance(e.value, ValueError) and e.value.key == key


def test_the_layout_refusal_says_which_layout_is_supported(tmp_path):
    text, _, _ = BAD["swapped spins"]
    with pytest.raises(VehicleFileError, match=r"supported: quad-X only, 4 rotors .* PX4 output order"):
        parse_vehicle(text.encode(), "x.toml")


def test_an_unknown_name_is_not_a_file_error():
    with pytest.raises(UnknownVehicleError, match=r"expected a shipped vehicle .*crazyflie.*seed.* or a path"):
        resolve_vehicle("hexacopter")
    with pytest.raises(VehicleFileError, match=r"nope\.toml: cannot read"):
        resolve_vehicle("nope.toml")
