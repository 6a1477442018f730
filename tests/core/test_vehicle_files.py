"""Vehicle files (core.vehicle_file): the shipped presets read back to today's presets field by
field, every bad file is refused with one line naming the file and the key, any flyable rotor layout
and output order is taken as written (and an unflyable one refused), and the writer/reader round
trip."""

import dataclasses
import math
import re

import pytest

from quadpilot.core.params import Rotor, VehicleParams, quad_x
from quadpilot.core.vehicle_file import (
    PRESETS,
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


def test_the_presets_are_px4_quad_x_in_px4_output_order():
    """Each preset's rotors are PX4's quad-X (`core.params.quad_x`, airframe 4001_quad_x: output 1
    front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW; FRD, y right)."""
    for name in ("seed", "crazyflie"):
        assert PRESETS[name].rotors == list(quad_x(PRESETS[name].arm))
    signs = [(math.copysign(1, r.x), math.copysign(1, r.y), r.spin) for r in PRESETS["px4_sih_quadx"].rotors]
    assert signs == [(1, 1, "ccw"), (-1, -1, "ccw"), (1, -1, "cw"), (-1, 1, "cw")]


# rotor blocks of a "+" frame numbered clockwise from the front: (x, y, spin) in FRD
PLUS = ((0.15, 0.0, "ccw"), (0.0, 0.15, "cw"), (-0.15, 0.0, "ccw"), (0.0, -0.15, "cw"))


def _with_rotors(rotors) -> str:
    head = HEAVY.strip().split("[[rotor]]")[0]
    blocks = [f'[[rotor]]\nx = {x}\ny = {y}\nspin = "{s}"\n' for x, y, s in rotors]
    return head + "\n".join(blocks)


@pytest.mark.parametrize(
    "rotors",
    [
        PLUS,
        # PX4's quad-X with its outputs permuted (3, 1, 4, 2)
        ((0.1, -0.1, "cw"), (0.1, 0.1, "ccw"), (-0.1, 0.1, "cw"), (-0.1, -0.1, "ccw")),
        # RotorPy's hummingbird numbering, and a non-square frame (wider than long)
        ((0.08, -0.12, "cw"), (0.08, 0.12, "ccw"), (-0.08, 0.12, "cw"), (-0.08, -0.12, "ccw")),
    ],
    ids=["plus", "permuted-quad-x", "wide-x"],
)
def test_any_flyable_layout_is_taken_as_written(rotors):
    v = parse_vehicle(_with_rotors(rotors).encode(), "frame.toml")
    assert v.rotors == [Rotor(x, y, s) for x, y, s in rotors]
    assert v.arm == pytest.approx(sum(math.hypot(x, y) for x, y, _ in rotors) / 4, rel=1e-12)


def test_an_idle_speed_is_taken():
    v = parse_vehicle(_variant(omega_min="150.0").encode(), "idle.toml")
    assert v.omega_min == 150.0


def test_the_shipped_px4_sih_file_holds_px4_and_rotorpy_numbers():
    """PX4 SIH parameters (sih_params.c defaults) and RotorPy 3.0.0's px4_sihsim_quadx_params, the
    simulator a policy for it flies against."""
    from rotorpy.vehicles.px4_sihsim_quadx_params import quad_params as rp

    v = resolve_vehicle("px4_sih_quadx")
    assert (v.mass, v.ixx, v.iyy, v.izz) == (1.0, 0.025, 0.025, 0.03)  # SIH_MASS, SIH_IXX/IYY/IZZ
    assert (v.mass, v.ixx, v.iyy, v.izz) == (rp["mass"], rp["Ixx"], rp["Iyy"], rp["Izz"])
    assert v.max_thrust == pytest.approx(5.0, rel=1e-12)  # SIH_T_MAX, N
    assert v.k_m * v.max_thrust == pytest.approx(0.1, rel=1e-12)  # SIH_Q_MAX, N m
    assert v.motor_tau == 0.05 == rp["tau_m"]  # SIH_T_TAU
    assert (v.k_f, v.k_m * v.k_f, v.omega_max, v.omega_min) == pytest.approx(
        (rp["k_eta"], rp["k_m"], rp["rotor_speed_max"], rp["rotor_speed_min"]), rel=1e-12
    )
    for r, key, direction in zip(v.rotors, ("r1", "r2", "r3", "r4"), rp["rotor_directions"], strict=True):
        x, y_flu, _ = rp["rotor_pos"][key]
        assert (r.x, -r.y) == pytest.approx((x, y_flu), abs=1e-15)
        # RotorPy: +1 is a CW rotor (its yaw moment on the body is +z), −1 a CCW one
        assert r.spin == ("cw" if direction > 0 else "ccw")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_written_file_reads_back_bit_for_bit(name, tmp_path):
    edited = dict(name="x1", mass=0.9, motor_tau=0.03, drag=0.2, c_dx=0.005, c_dy=0.007, c_dz=0.01)
    edited.update(k_d=1.2e-4, k_h=3e-3)
    for v in (PRESETS[name], dataclasses.replace(PRESETS[name], **edited)):
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
    "negative idle speed": (_variant(omega_min="-1.0"), "omega_min", ">= 0"),
    "idle speed at full speed": (_variant(omega_min="2400.0"), "omega_min", "below omega_max"),
    "anisotropic drag": (_variant(drag="[0.1, 0.2, 0.1]"), "drag", "equal"),
    "drag of two": (_variant(drag="[0.1, 0.1]"), "drag", "three"),
    "quadratic drag of two": (_variant(drag_quadratic="[0.1, 0.1]"), "drag_quadratic", "three numbers"),
    "quadratic drag a number": (_variant(drag_quadratic="0.1"), "drag_quadratic", "three numbers"),
    "negative quadratic drag": (_variant(drag_quadratic="[0.1, -0.1, 0.1]"), "drag_quadratic", ">= 0"),
    "quadratic drag a string": (_variant(drag_quadratic='[0.1, "x", 0.1]'), "drag_quadratic", "expected a number"),
    "unknown key": (_variant(arm="0.1"), "arm", "unknown key"),
    "bad name": (_variant(name='"two words"'), "name", "letters"),
    "name a number": (_variant(name="3"), "name", "letters"),
    "name of a hidden file": (_variant(name='".heavy"'), "name", "the first a letter or digit"),
    "name a parent directory": (_variant(name='".."'), "name", "the first a letter or digit"),
    "name an option": (_variant(name='"-heavy"'), "name", "the first a letter or digit"),
    "no rotor": (_variant().split("[[rotor]]")[0], "rotor", "missing"),
    "three rotors": ("[[rotor]]".join(_variant().split("[[rotor]]")[:4]), "rotor", "3 rotor table(s); expected 4"),
    "six rotors": (_with_rotors(PLUS + PLUS[:2]), "rotor", "6 rotor table(s); expected 4"),
    "rotor a number": (_variant().split("[[rotor]]")[0] + "rotor = 4\n", "rotor", "[[rotor]] tables"),
    "rotor unknown key": (_variant().replace('spin = "cw"', 'spin = "cw"\nz = 0.0', 1), "rotor[3].z", "unknown"),
    "rotor without spin": (_variant().replace('spin = "cw"\n', "", 1), "rotor[3].spin", "missing"),
    "rotor bad spin": (_variant().replace('"cw"', '"clockwise"', 1), "rotor[3].spin", '"cw" or "ccw"'),
    "rotor x a string": (_variant().replace("x = 0.1", 'x = "front"', 1), "rotor[1].x", "expected a number"),
    "rotors on one line": (
        _with_rotors(((0.2, 0.0, "ccw"), (0.1, 0.0, "cw"), (-0.1, 0.0, "ccw"), (-0.2, 0.0, "cw"))),
        "rotor",
        "cannot make thrust, roll, pitch and yaw",
    ),
    "every rotor ccw": (
        _with_rotors(((0.1, 0.1, "ccw"), (-0.1, -0.1, "ccw"), (0.1, -0.1, "ccw"), (-0.1, 0.1, "ccw"))),
        "rotor",
        "cannot make thrust, roll, pitch and yaw",
    ),
    "centre of mass behind the rotors": (
        _with_rotors(((0.3, 0.1, "ccw"), (0.1, -0.1, "ccw"), (0.3, -0.1, "cw"), (0.1, 0.1, "cw"))),
        "rotor",
        "negative thrust",
    ),
    "every rotor at the centre": (_with_rotors(((0.0, 0.0, "ccw"),) * 2 + ((0.0, 0.0, "cw"),) * 2), "rotor", "centre"),
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


def test_an_unknown_name_is_not_a_file_error():
    with pytest.raises(UnknownVehicleError, match=r"expected a shipped vehicle .*crazyflie.*seed.* or a path"):
        resolve_vehicle("hexacopter")
    with pytest.raises(VehicleFileError, match=r"nope\.toml: cannot read"):
        resolve_vehicle("nope.toml")


def test_rotorpys_parasitic_drag_reads_as_it_is_written():
    """drag_quadratic takes RotorPy's c_Dx, c_Dy, c_Dz as its airframe modules give them."""
    from rotorpy.vehicles.hummingbird_params import quad_params as rp

    v = parse_vehicle(_variant(drag_quadratic=f"[{rp['c_Dx']}, {rp['c_Dy']}, {rp['c_Dz']}]").encode())
    assert (v.c_dx, v.c_dy, v.c_dz) == (rp["c_Dx"], rp["c_Dy"], rp["c_Dz"])
    assert "drag_quadratic" not in vehicle_to_toml(parse_vehicle(_variant().encode()))  # none: not written


def test_differences_name_each_parameter_with_its_unit_and_every_number_has_one():
    from quadpilot.core.vehicle_file import UNITS, differences, get_preset

    numbers = {f.name for f in dataclasses.fields(VehicleParams)} - {"name", "rotors"}
    assert set(UNITS) == numbers
    a = get_preset("px4_sih_quadx")
    b = dataclasses.replace(a, name="other", mass=1.5, k_f=a.k_f * (1 + 1e-9))
    assert differences(a, a) == [] and differences(a, dataclasses.replace(a, name="x")) == []
    assert differences(a, b) == ["mass 1 vs 1.5 kg", f"k_f {a.k_f!r} vs {b.k_f!r} N/(rad/s)²"]
    wider = dataclasses.replace(a, arm=None, rotors=[Rotor(1.25 * r.x, 1.25 * r.y, r.spin) for r in a.rotors])
    assert [d.split(" ")[0] for d in differences(a, wider)] == ["arm", "rotors"]
    assert differences(a, wider)[1].endswith("(x, y in m, FRD)")
