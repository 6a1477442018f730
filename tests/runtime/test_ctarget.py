"""The generated C kernel on an emulated Cortex-M: the shipped hover MLP and hover LSTM cross-built
for the Cortex-M4F and the Cortex-M7 (arm-none-eabi-gcc, hard float, -Wall -Wextra -Werror) and
booted in QEMU (mps2-an386, mps2-an500). Each image checks the model's golden vectors itself and
then runs 1,000 random in-envelope observations and a recorded closed-loop flight (the LSTM's
state carried across its steps); every motor command it writes back is compared with the NumPy
backend (max abs difference <= 1e-5) and with the same policy.c compiled for this host.

Needs Debian's gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm: without them these
tests skip with one line naming the apt-get install, and fail instead when the environment
variable CI is set (.ci/run installs them). One boot per model and core: a few seconds.
"""

from __future__ import annotations

import dataclasses
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest

from quadpilot.ccode import generate as cgen
from quadpilot.ccode import harness as charness
from quadpilot.ccode import target as ctarget
from quadpilot.modelfile.model import initializer_arrays, read_model
from quadpilot.runtime.backends import load_policy
from quadpilot.runtime.cbackend import find_compiler

MODELS = Path(__file__).parents[2] / "models"
TOLERANCE = 1e-5
RANDOM_OBS, FLIGHT_STEPS = 1_000, 300
HUNG_TIMEOUT_S = 3.0
"""s: many times a boot of the hover image (golden vectors alone), short enough for a test."""
CASES = [(m, t) for m in ("hover", "hover_lstm") for t in ("cortex-m4f", "cortex-m7")]


def need_tools() -> None:
    missing = ctarget.missing_tools()
    if missing:
        message = f"{', '.join(missing)} not installed; install with: {ctarget.APT_INSTALL}"
        if os.environ.get("CI"):
            pytest.fail(f"CI: {message}")
        pytest.skip(message)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(model, target) → (image, run of the inputs, inputs, resets, numpy policy), built lazily."""
    cache = {}

    def get(model: str, target: str):
        if (model, target) not in cache:
            need_tools()
            path = MODELS / model / "policy.onnx"
            onnx_model, info = read_model(path)
            code = cgen.generate(info, initializer_arrays(onnx_model))
            image = ctarget.build_image(code, info, tmp_path_factory.mktemp(f"{model}_{target}"), target)
            policy = load_policy(path, backend="numpy")
            obs, resets = ctarget.check_inputs(policy, RANDOM_OBS, FLIGHT_STEPS)
            run = ctarget.run_image(image, ctarget.encode_inputs(obs, resets))
            cache[model, target] = (image, run, obs, resets, policy)
        return cache[model, target]

    return get


@pytest.mark.parametrize("model,target", CASES)
def test_image_matches_the_numpy_backend_in_qemu(built, model, target):
    image, run, obs, resets, policy = built(model, target)
    assert run.status == 0, run.console
    assert run.trailer["records"] == len(obs) == len(run.motors)
    want = ctarget.replay(policy, obs, resets)
    diff = np.abs(run.motors.astype(np.float64) - want)
    print(
        f"{model} on {image.target.core} ({image.target.machine}): {len(obs):,} steps, max abs difference "
        f"from numpy {diff.max():.2e}; {run.instructions[:, 0].mean():,.0f} instructions per step"
    )
    assert diff.max() <= TOLERANCE
    assert want.std() > 0.02  # the commands span a range: the comparison is not blind
    k = len(policy.info.golden_obs)
    assert np.abs(run.motors[:k] - policy.info.golden_action).max() <= TOLERANCE


@pytest.mark.parametrize("target", ["cortex-m4f", "cortex-m7"])
def test_lstm_image_carries_its_state_across_steps(built, target):
    """Not blind to the state: the same inputs with the state zeroed at every step give other commands."""
    _, run, obs, _, policy = built("hover_lstm", target)
    every_step = ctarget.replay(policy, obs, np.ones(len(obs), bool))
    assert np.abs(run.motors - every_step).max() > 1e-2


@pytest.mark.skipif(find_compiler() is None, reason="no C compiler found (CC, cc, gcc or clang)")
@pytest.mark.parametrize("model,target", CASES)
def test_host_and_target_builds_of_the_same_source_agree(built, model, target):
    image, run, obs, resets, _ = built(model, target)
    host = load_policy(MODELS / model / "policy.onnx", backend="c")
    assert host.code.source == (image.elf.parent / cgen.SOURCE_NAME).read_text()  # the same policy.c
    diff = np.abs(run.motors - ctarget.replay(host, obs, resets)).max()
    print(f"{model}: host C vs {image.target.core} max abs difference {diff:.2e}")
    assert diff <= TOLERANCE


def test_image_alone_checks_the_golden_vectors(built, tmp_path):
    """Booted without an input file the image replays the golden vectors and exits 0; built from a
    file whose golden commands were altered by 2e-5 it exits 1 with a one-line message."""
    image, _, _, _, policy = built("hover", "cortex-m4f")
    alone = ctarget.run_image(image)
    assert alone.status == 0 and "golden vectors reproduced" in alone.console
    info = dataclasses.replace(policy.info, golden_action=policy.info.golden_action + np.float32(2e-5))
    onnx_model, _ = read_model(MODELS / "hover" / "policy.onnx")
    code = cgen.generate(info, initializer_arrays(onnx_model))
    bad = ctarget.run_image(ctarget.build_image(code, info, tmp_path, "cortex-m4f"))
    assert bad.status == charness.EXIT_GOLDEN
    assert re.search(r"does not reproduce the model's golden vectors", bad.console)


def test_truncated_input_is_refused(built):
    image, _, obs, _, _ = built("hover", "cortex-m4f")
    data = ctarget.encode_inputs(obs[:3])
    assert ctarget.run_image(image, data[:-5]).status == charness.EXIT_INPUT


HANG = 'for (;;) __asm__ volatile("nop"); /* hung: never reaches main or a semihosting exit */'


def test_a_hung_image_is_killed_at_the_timeout(built, tmp_path, monkeypatch):
    """An image that really hangs (its reset handler spins before main, so no semihosting exit ever
    comes) is killed at the timeout; the same image without the loop boots and exits well within it,
    so the timeout is the hang's, not QEMU's start-up."""
    image, _, _, _, _ = built("hover", "cortex-m4f")
    assert ctarget.run_image(image, timeout=HUNG_TIMEOUT_S).status == 0
    onnx_model, info = read_model(MODELS / "hover" / "policy.onnx")
    code = cgen.generate(info, initializer_arrays(onnx_model))
    source, exit_line = charness.harness_source, "qp_exit((uint32_t)main());"
    assert source(info, code.network).count(exit_line) == 1
    monkeypatch.setattr(charness, "harness_source", lambda *a, **kw: source(*a, **kw).replace(exit_line, HANG))
    hung = ctarget.build_image(code, info, tmp_path, "cortex-m4f")
    assert HANG in (tmp_path / charness.HARNESS_NAME).read_text()
    t0 = time.monotonic()
    with pytest.raises(ctarget.CrossToolError, match=f"did not exit within {HUNG_TIMEOUT_S:g} s"):
        ctarget.run_image(hung, timeout=HUNG_TIMEOUT_S)
    assert time.monotonic() - t0 >= HUNG_TIMEOUT_S


@pytest.mark.parametrize("model,target", CASES)
def test_footprint_parts_add_up_and_the_counts_are_sane(built, model, target):
    image, run, _, _, _ = built(model, target)
    parts = ctarget.footprint(image)
    elf = ctarget.elf_sections(image)
    for section in (".text", ".rodata", ".data", ".bss"):
        assert sum(parts[section].values()) == elf.get(section, 0), section
        assert parts[section]["padding"] < 16, (section, parts[section])  # every input section was read from the map
    onnx_model, info = read_model(MODELS / model / "policy.onnx")
    weights = sum(a.size for a in cgen.generate(info, initializer_arrays(onnx_model)).network.arrays().values())
    assert 4 * weights <= parts[".rodata"]["policy"] <= 4 * weights + 64  # the weights, and a few constants
    assert parts[".data"].get("policy", 0) == 0 and parts[".bss"].get("policy", 0) == 0  # no state
    assert 38 <= run.instructions_per_tick <= 42  # the calibration loop: 25 MHz SysTick at 1 ns per instruction
    assert 0 < run.trailer["kernel_stack_bytes"] < run.trailer["stack_high_water_bytes"] < charness.STACK_BYTES
    assert run.ticks[:, 0].min() > 0


@pytest.fixture(scope="module")
def recorded():
    """docs/bench/embedded.json, the counts docs/embedded.md quotes, and whether this machine has the
    toolchain they were counted with (gcc, newlib, QEMU): only then must its counts be the same."""
    import json

    need_tools()
    doc = json.loads((Path(__file__).parents[2] / "docs" / "bench" / "embedded.json").read_text())
    here = ctarget.toolchain_versions()
    if any(here.get(k) != v for k, v in doc["toolchain"].items()):
        pytest.skip(f"docs/bench/embedded.json was counted with {doc['toolchain']}; this machine has {here}")
    return {r["case"]: r for r in doc["results"]}


@pytest.mark.parametrize("model,target", CASES)
def test_the_instruction_counts_are_the_ones_docs_bench_embedded_json_records(built, recorded, model, target):
    """QEMU's count is deterministic: with the recorded toolchain the benchmark's inputs (these) give
    the recorded counts exactly, on any host. A change to the kernel, the harness or the inputs (the
    flight is flown on core.dynamics) changes them: re-measure (docs/embedded.md)."""
    _, run, _, _, _ = built(model, target)
    per = run.instructions[:, 0]
    want = recorded[f"{model}@{target}"]["instructions"]
    got = {"mean": float(per.mean()), "min": float(per.min()), "max": float(per.max()), "steps": len(per)}
    assert got == pytest.approx(want, rel=0, abs=1e-6), "re-measure with the command in docs/embedded.md"


# --- quad-export --format c --target ------------------------------------------------------------


def test_quad_export_target_builds_and_boots_the_image(tmp_path, capsys):
    need_tools()
    from quadpilot.export.cli import main

    out = tmp_path / "hover_m7"
    argv = [str(MODELS / "hover" / "policy.pt"), "--format", "c", "--target", "cortex-m7", "-o", str(out)]
    assert main([*argv, "--parity-samples", "100"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"built \S+policy\.elf for the Cortex-M7 \(-mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard", text)
    assert "booted in QEMU mps2-an500: golden vectors reproduced (exit status 0)" in text
    for name in ("policy.c", "policy.h", "harness.c", "cortex-m.ld", "policy.elf"):
        assert (out / name).is_file(), name
    run = ctarget.run_image(ctarget.Image(out / "policy.elf", out / "policy.map", ctarget.TARGETS["cortex-m7"], (), 0))
    assert run.status == 0  # the ELF on disk, booted by hand


def test_quad_export_target_refusals_are_one_line(tmp_path, capsys, monkeypatch):
    from quadpilot.export.cli import main

    pt = str(MODELS / "hover" / "policy.pt")
    assert main([pt, "--target", "cortex-m4f", "-o", str(tmp_path / "p.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "quad-export: error: --target cortex-m4f needs --format c (it cross-compiles the C)"
    assert main([pt, "--format", "c", "--target", "cortex-m0"]) == 2
    assert "invalid choice" in capsys.readouterr().err
    monkeypatch.setattr(ctarget, "find_tool", lambda name: None)  # a machine without the cross compiler
    assert main([pt, "--format", "c", "--target", "cortex-m4f", "-o", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"install it with: {ctarget.APT_INSTALL}" in err and "Traceback" not in err
    assert not (tmp_path / "c").exists()  # refused before anything was written
