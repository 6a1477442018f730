"""Hostile vehicle files: what is not a vehicle file at all (not TOML, not UTF-8, too big, a
directory, a device, deep nesting, huge numbers) is refused with one line naming the file, and the
console scripts turn it into one line on stderr and exit code 1 (an unknown name: exit code 2)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.core.vehicle_file import MAX_FILE_BYTES, VEHICLES_DIR, VehicleFileError, load_vehicle_file, parse_vehicle


def _refused(path, *words):
    with pytest.raises(VehicleFileError) as e:
        load_vehicle_file(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    for w in words:
        assert w in msg, msg
    return msg


def test_not_toml(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text("mass = = 1\n[[rotor\n")
    _refused(p, "not valid TOML")


def test_not_utf8(tmp_path):
    p = tmp_path / "v.toml"
    p.write_bytes(b'name = "\xff\xfe"\n')
    _refused(p, "not UTF-8")


def test_too_big_is_refused_without_reading_it_whole(tmp_path):
    p = tmp_path / "v.toml"
    p.write_bytes(b"#" * (MAX_FILE_BYTES * 4))
    _refused(p, "too big")


def test_a_directory_and_a_device(tmp_path):
    _refused(tmp_path, "is a directory")
    with pytest.raises(VehicleFileError, match="/dev/zero: too big"):  # endless: read stops at the limit
        load_vehicle_file("/dev/zero")


def test_deep_nesting_and_huge_numbers(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text("mass = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(VehicleFileError):  # refused, whatever tomllib makes of the depth
        load_vehicle_file(p)
    p.write_text("name = 'x'\nmass = 1" + "0" * 400 + "\n")
    _refused(p, "missing")  # a 400-digit integer is a TOML integer; the missing keys are named first


def test_a_key_with_a_newline_stays_one_line(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text('"ma\\nss" = 1\n')
    msg = _refused(p, "unknown key")
    assert "\n" not in msg


@settings(derandomize=True, database=None, max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_arbitrary_bytes_give_a_vehicle_or_one_line(raw):
    try:
        parse_vehicle(raw, "fuzz.toml")
    except VehicleFileError as e:
        assert "\n" not in str(e) and str(e).startswith("fuzz.toml: ")


@pytest.mark.parametrize("prog", ["quad-train", "quad-sitl"])
def test_console_scripts_refuse_a_bad_file_with_exit_1_and_an_unknown_name_with_exit_2(prog, tmp_path, capsys):
    if prog == "quad-train":
        pytest.importorskip("torch")
        from quadpilot.train.cli import main

        base = ["--task", "hover", "--out", str(tmp_path / "run")]
    else:
        from quadpilot.sitl import main

        base = ["--episodes", "1"]
    bad = tmp_path / "bad.toml"
    seed = (VEHICLES_DIR / "seed.toml").read_text(encoding="utf-8")
    bad.write_text(seed.replace("mass = 0.665", "mass = -0.665"), encoding="utf-8")
    assert main([*base, "--vehicle", str(bad)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "mass" in err[0], err
    assert main([*base, "--vehicle", "hexacopter"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hexacopter" in err[0] and "shipped vehicle" in err[0], err
    assert not (tmp_path / "run").exists()


# --- rotor lists: files and metadata ------------------------------------------------------------

_HEAD = (VEHICLES_DIR / "seed.toml").read_text(encoding="utf-8").split("[[rotor]]")[0]


def test_thousands_of_rotor_tables_are_refused_by_count(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text(_HEAD + '[[rotor]]\nx = 0.1\ny = 0.1\nspin = "cw"\n' * 1500, encoding="utf-8")
    _refused(p, "rotor: 1500 rotor table(s); expected 4")


@settings(derandomize=True, database=None, max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(allow_nan=False, allow_infinity=False, width=64),
            st.floats(allow_nan=False, allow_infinity=False, width=64),
            st.sampled_from(["cw", "ccw"]),
        ),
        min_size=4,
        max_size=4,
    )
)
def test_any_rotor_positions_give_a_vehicle_or_one_line(rotors):
    """Positions from 1e-308 to 1e308, on a line, all in one place: a flyable vehicle or one line
    naming the rotor key, never another exception (an overflow, a singular matrix)."""
    text = _HEAD + "".join(f'[[rotor]]\nx = {x!r}\ny = {y!r}\nspin = "{s}"\n' for x, y, s in rotors)
    try:
        v = parse_vehicle(text.encode(), "fuzz.toml")
    except VehicleFileError as e:
        assert "\n" not in str(e) and str(e).startswith("fuzz.toml: rotor"), str(e)
    else:
        assert np.all(np.isfinite(v.hover_commands)) and np.all(v.hover_thrusts > 0)


@pytest.mark.parametrize(
    "rotors",
    [
        "rotors",
        {"x": 0.1},
        [[0.1, 0.1, "cw"]] * 4,
        [{"x": 0.1, "y": 0.1, "spin": "cw", "z": 1}] * 4,
        [{"x": [0.1] * 1000, "y": 0.1, "spin": "cw"}] * 4,
        [{"x": 0.1, "y": 0.1, "spin": "clockwise" * 1000}] * 4,
        [{"x": 1e308, "y": 1e308, "spin": "cw"}] * 4,
        [{"x": True, "y": 0.1, "spin": "cw"}] * 4,
        list(range(10**6)),
    ],
    ids=["string", "table", "lists", "extra-key", "x-a-list", "long-spin", "overflow", "boolean", "a-million"],
)
def test_hostile_rotor_metadata_is_one_line(rotors):
    """What checkpoint or ONNX metadata could hold in place of a rotor list (VehicleParams(**json)):
    a ValueError of one short line."""
    import dataclasses

    from quadpilot.core.params import VehicleParams
    from quadpilot.core.vehicle_file import SEED_VEHICLE

    d = {**dataclasses.asdict(SEED_VEHICLE), "rotors": rotors}
    with pytest.raises(ValueError) as e:
        VehicleParams(**d)
    msg = str(e.value)
    assert "\n" not in msg and "rotors" in msg and len(msg) < 300, msg
