"""policy.tar in NumPy (runtime.rltools_tar): the forward against foundation-policy's own inference,
deterministic bytes, and the reader's refusals, each in one line."""

from __future__ import annotations

import functools
import io
import tarfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from raptor_files import (
    FOUNDATION_NAME,
    example_index,
    flip_low_byte,
    forward,
    foundation,
    members,
    patch_float,
    retar,
    wider_first_layer,
)

from quadpilot.runtime import rltools_tar as rt


@functools.cache
def _foundation():
    return foundation()


@functools.cache
def good_bytes() -> bytes:
    w, ex_in, ex_out = _foundation()
    return rt.policy_tar_bytes(w, ex_in, ex_out, FOUNDATION_NAME)


def refused(data: bytes, *words: str) -> str:
    with pytest.raises(rt.PolicyTarError) as e:
        rt.parse_policy_tar(data)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg
    return msg


def test_foundation_policy_has_mc_raptor_shape():
    _, ex_in, ex_out = _foundation()
    assert rt.N_PARAMETERS == 2084  # "about 2,100 parameters": blob/policy.h's dense-GRU-dense
    assert ex_in.shape == (500, 2, 22) and ex_out.shape == (500, 2, 4)


def test_gru_forward_matches_foundation_policy_inference():
    import foundation_policy

    w, ex_in, ex_out = _foundation()
    theirs = foundation_policy.Raptor()
    ours = forward(w, ex_in)
    assert np.max(np.abs(ours - theirs.evaluate(ex_in))) <= 1e-5
    assert np.max(np.abs(ours - ex_out)) <= 1e-5  # and RLtools' own stored outputs
    # inputs of another scale, step by step with the state carried
    x = np.random.default_rng(1).normal(0, 2, (200, 3, 22)).astype(np.float32)
    theirs.reset()
    steps = np.stack([theirs.evaluate_step(x[t].astype(np.float64)) for t in range(len(x))])
    assert np.max(np.abs(forward(w, x) - steps)) <= 1e-5


def test_round_trip_and_same_bytes_for_same_input(tmp_path):
    w, ex_in, ex_out = _foundation()
    digest = rt.write_policy_tar(tmp_path / "policy.tar", w, ex_in, ex_out, FOUNDATION_NAME)
    data = (tmp_path / "policy.tar").read_bytes()
    assert data == good_bytes() == rt.policy_tar_bytes(dict(reversed(w.items())), ex_in, ex_out, FOUNDATION_NAME)
    assert (tmp_path / "policy.tar.sha256").read_text() == f"{rt.sha256_hex(data)}  policy.tar\n"
    assert digest == rt.sha256_hex(data)
    back = rt.read_policy_tar(tmp_path / "policy.tar")
    assert back.checkpoint_name == FOUNDATION_NAME and back.sha256 == digest
    for name in rt.WEIGHT_SHAPES:
        assert np.array_equal(back.weights[name], w[name])
    assert np.array_equal(back.example_in, ex_in) and np.array_equal(back.example_out, ex_out)
    assert back.replay_max_difference <= 1e-5
    assert list(members(data)) == rt.MEMBER_NAMES
    assert members(data)["actor/meta"] == f"checkpoint_name: {FOUNDATION_NAME}\ntype: sequential\n".encode()


def test_writer_refuses_what_mc_raptor_could_not_load():
    w, ex_in, ex_out = _foundation()
    with pytest.raises(rt.PolicyTarError, match=r"layers/0/weights: shape \(32, 22\), expected \(16, 22\)"):
        rt.policy_tar_bytes({**w, "layers/0/weights": np.zeros((32, 22))}, ex_in, ex_out)
    with pytest.raises(rt.PolicyTarError, match="unknown \\['layers/3/weights'\\]"):
        rt.policy_tar_bytes({**w, "layers/3/weights": np.zeros(1)}, ex_in, ex_out)
    with pytest.raises(rt.PolicyTarError, match="not finite"):
        rt.policy_tar_bytes({**w, "layers/2/biases": np.array([0, np.nan, 0, 0])}, ex_in, ex_out)
    with pytest.raises(rt.PolicyTarError, match="is not these weights' output"):
        rt.policy_tar_bytes(w, ex_in, ex_out + 1e-3)
    with pytest.raises(rt.PolicyTarError, match="checkpoint name"):
        rt.policy_tar_bytes(w, ex_in, ex_out, "bad\nname")


def test_reader_refuses_a_changed_weight():
    bad = patch_float(good_bytes(), "actor/layers/1/weights_hidden/parameters/data", 7, 0.9)
    refused(bad, "does not replay")


def test_reader_refuses_damage_beyond_mc_raptors_five_steps():
    at = example_index(300, 1, 2, rt.ACTION_DIM)
    refused(patch_float(good_bytes(), "example/output/data", at, 0.25), "does not replay")
    at = example_index(300, 0, 5, rt.OBS_DIM)
    bad = patch_float(good_bytes(), "example/input/data", at, np.nan)
    refused(bad, "example/input/data", "(300, 0, 5)", "not finite")


def test_low_order_byte_passes_every_replay_and_the_sha256_catches_it(tmp_path):
    bad = flip_low_byte(good_bytes(), "actor/layers/0/weights/parameters/data", 3)
    assert bad != good_bytes()
    assert rt.parse_policy_tar(bad).replay_max_difference <= 1e-5  # no replay can see it
    path = tmp_path / "policy.tar"
    path.write_bytes(bad)
    rt.sha256_path(path).write_text(f"{rt.sha256_hex(good_bytes())}  policy.tar\n")
    with pytest.raises(rt.PolicyTarError, match=r"SHA-256 .* expected .* \(file changed\)"):
        rt.read_policy_tar(path)
    with pytest.raises(rt.PolicyTarError, match="SHA-256"):
        rt.read_policy_tar(path, expected_sha256=rt.sha256_hex(good_bytes()))


def test_reader_refuses_other_shapes_and_metadata():
    refused(wider_first_layer(good_bytes()), "actor/layers/0/weights/parameters/meta", "(16, 22)")
    c = members(good_bytes())
    c["example/output/meta"] = c["example/output/meta"].replace(b"float32", b"float64")
    refused(retar(c), "example/output/meta", "expected float32")
    c = members(good_bytes())
    c["actor/layers/2/meta"] = b"activation_function: RELU\ntype: dense\n"
    refused(retar(c), "actor/layers/2/meta")
    c = members(good_bytes())
    c["actor/meta"] = b"checkpoint_name: " + b"x" * 300 + b"\ntype: sequential\n"
    refused(retar(c), "actor/meta", "at most 256")


def test_reader_refuses_truncated_and_foreign_archives():
    data = good_bytes()
    for cut in (100, 600, 20_000, len(data) // 2, len(data) - 20_000):
        refused(data[:cut])
    refused(b"\x1f\x8b" + data[2:])
    refused(b"", "not a readable tar archive")
    refused(b"x" * (rt.MAX_FILE_BYTES + 1), "at most")


def test_reader_refuses_extra_duplicate_and_link_members():
    c = members(good_bytes())
    refused(retar({**c, "actor/layers/3/meta": b"type: dense\n"}), "unexpected member 'actor/layers/3/meta'")
    refused(retar({**c, "../../etc/passwd": b""}), "unexpected member")
    # the same member twice: RLtools would read the first, tarfile the last
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for name, raw in [*c.items(), ("actor/layers/0/biases/parameters/data", bytes(64))]:
            info = tarfile.TarInfo(name)
            info.size = len(raw)
            tar.addfile(info, io.BytesIO(raw))
    refused(buf.getvalue(), "twice")
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for name, raw in c.items():
            info = tarfile.TarInfo(name)
            if name == "actor/meta":
                info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
                tar.addfile(info)
            else:
                info.size = len(raw)
                tar.addfile(info, io.BytesIO(raw))
    refused(buf.getvalue(), "not a plain ustar file")


def test_reader_names_the_file_in_its_one_line(tmp_path):
    path = tmp_path / "policy.tar"
    path.write_bytes(good_bytes()[:5000])
    with pytest.raises(rt.PolicyTarError) as e:
        rt.read_policy_tar(path)
    assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)
    with pytest.raises(rt.PolicyTarError, match="cannot read"):
        rt.read_policy_tar(tmp_path / "missing.tar")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(draw=st.data(), where=st.sampled_from(["headers", "anywhere", "cut"]))
def test_any_damaged_file_is_refused_in_one_line_or_replays(draw, where):
    """Bytes changed in the headers (where the tar parser looks) or anywhere, or the file cut
    anywhere: the reader refuses with a PolicyTarError or returns a policy whose example replays."""
    data = bytearray(good_bytes())
    n_blocks = len(data) // 512
    if where == "cut":
        data = data[: draw.draw(st.integers(0, len(data) - 1))]
    for _ in range(draw.draw(st.integers(1, 6)) if where != "cut" else 0):
        if where == "headers":  # a header block's fields: name, mode, ids, size, mtime, checksum, type, magic
            at = 512 * draw.draw(st.integers(0, n_blocks - 1)) + draw.draw(st.integers(0, 264))
        else:
            at = draw.draw(st.integers(0, len(data) - 1))
        data[at] = draw.draw(st.integers(0, 255))
    try:
        back = rt.parse_policy_tar(bytes(data))
    except rt.PolicyTarError as e:
        assert "\n" not in str(e)
    else:
        assert back.replay_max_difference <= rt.REPLAY_TOLERANCE
