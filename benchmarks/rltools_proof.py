"""Our policy.tar against RLtools' own code, as PX4's mc_raptor loads it: the record docs/px4.md quotes.

    .venv/bin/python benchmarks/rltools_proof.py --out docs/bench/rltools_px4.json \\
        --px4-include /path/to/rl-tools/include --px4-commit 15940da2a8334d7532c4a5650ee4e09526206414

Writes the RAPTOR foundation policy (PyPI foundation-policy) as policy.tar with
`runtime.rltools_tar.write_policy_tar`, then, for each RLtools (the pinned `rltools` sdist from PyPI,
and the checkout given with --px4-include, which must be at the commit PX4 pins for mc_raptor),
builds tests/px4/harness/raptor_check.cpp and records: mc_raptor's start-up check on the file, RLtools'
L2F executor at mc_raptor's timing on 2,000 gyro updates against our forward and foundation-policy's
(largest action difference), whether RLtools' own writer writes the same bytes, and what the loader
does with each damaged copy (tests/px4/raptor_files.DAMAGE), next to what our reader says.
The figures are differences of float32 arithmetic, not timings: the load on the machine does not
change them.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "px4"))

import raptor_build as build  # noqa: E402
import raptor_files as files  # noqa: E402

from quadpilot.runtime import rltools_tar as rt  # noqa: E402

N_GYRO = 2000


def _outcome(done) -> dict:
    text = (done.stdout + done.stderr).strip().splitlines()
    return {"exit": done.returncode, "last_line": text[-1] if text else ""}


def _loader(harness: Path, good: Path, work: Path) -> dict:
    check = build.run(harness, "check", good)
    diff = [ln for ln in check.stdout.splitlines() if ln.startswith("Checkpoint test diff: ")]
    obs = files.observations(N_GYRO)
    obs.tofile(work / "obs.f32")
    fly = build.run(harness, "fly", good, work / "obs.f32", work / "actions.f32")
    if check.returncode != 0 or fly.returncode != 0:
        raise SystemExit(f"rltools_proof: the harness refused the good file:\n{check.stdout}{fly.stdout}")
    theirs = np.fromfile(work / "actions.f32", dtype="<f4").reshape(-1, rt.ACTION_DIM)
    ours = files.fly_like_mc_raptor(files.our_stepper(rt.read_policy_tar(good).weights), obs)
    package = files.fly_like_mc_raptor(files.foundation_stepper(), obs)
    save = build.run(harness, "save", good, work / "theirs.tar")
    theirs_tar = (work / "theirs.tar").read_bytes() if save.returncode == 0 else b""
    same = theirs_tar == good.read_bytes()
    damage = {}
    for how, damaged in files.DAMAGE.items():
        path = work / "damaged.tar"
        path.write_bytes(damaged(good.read_bytes()))
        damage[how] = _outcome(build.run(harness, "check", path))
    return {
        "check_mean_abs_diff": float(diff[0].split(": ")[1]),
        "check_passed": True,
        "gyro_updates": N_GYRO,
        "native_steps": int(fly.stdout.split(" gyro updates, ")[1].split()[0]),
        "max_action_diff_our_forward": float(np.max(np.abs(theirs - ours))),
        "max_action_diff_foundation_policy": float(np.max(np.abs(theirs - package))),
        "rltools_writer_writes_the_same_bytes": bool(same),
        "damage": damage,
    }


def _our_reader(good: Path, work: Path, with_sha256: bool) -> dict:
    """What read_policy_tar says of each damaged copy, with the good file's SHA-256 beside it or not."""
    out = {}
    for how, damaged in files.DAMAGE.items():
        path = work / "damaged.tar"
        path.write_bytes(damaged(good.read_bytes()))
        rt.sha256_path(path).unlink(missing_ok=True)
        if with_sha256:
            rt.sha256_path(path).write_bytes(rt.sha256_path(good).read_bytes())
        try:
            rt.read_policy_tar(path)
            out[how] = "accepted"
        except rt.PolicyTarError as e:
            out[how] = str(e).split(": ", 1)[1]  # without the temporary path
    return out


def _low_byte_effect(good: Path) -> float:
    """How far the example outputs move when one weight's low-order byte changes (DAMAGE's case)."""
    damaged = files.DAMAGE["a weight's low-order byte changed"](good.read_bytes())
    w0, w1 = rt.parse_policy_tar(good.read_bytes()), rt.parse_policy_tar(damaged)
    return float(np.max(np.abs(files.forward(w1.weights, w0.example_in) - files.forward(w0.weights, w0.example_in))))


def _px4_blob(blob_path: Path, weights: dict, harnesses: dict[str, Path]) -> dict:
    """PX4's own policy.tar (its mc_raptor blob) against our reader and writer and each loader."""
    blob = blob_path.read_bytes()
    p = rt.parse_policy_tar(blob)
    ours = rt.policy_tar_bytes(p.weights, p.example_in, p.example_out, p.checkpoint_name)
    checks = {}
    for name, harness in harnesses.items():
        done = build.run(harness, "check", blob_path)
        diff = [ln for ln in done.stdout.splitlines() if ln.startswith("Checkpoint test diff: ")]
        checks[name] = {"exit": done.returncode, "check_mean_abs_diff": float(diff[0].split(": ")[1])}
    return {
        "sha256": rt.sha256_hex(blob),
        "bytes": len(blob),
        "checkpoint_name": p.checkpoint_name,
        "our_replay_max_difference": p.replay_max_difference,
        "weights_equal_foundation_policy": all(np.array_equal(p.weights[n], weights[n]) for n in weights),
        "our_writer_writes_it_and_two_end_blocks": ours == blob + bytes(2 * 512),
        "loaders": checks,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--px4-include", type=Path, help="include/ of RLtools at the commit PX4 pins")
    p.add_argument("--px4-commit", help="that commit (recorded as given)")
    p.add_argument("--px4-blob", type=Path, help="PX4's src/modules/mc_raptor/blob/policy.tar")
    p.add_argument("--px4-blob-commit", help="the rl-tools/px4-blob commit it is from (recorded as given)")
    a = p.parse_args(argv)
    w, ex_in, ex_out = files.foundation()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        good = work / "policy.tar"
        digest = rt.write_policy_tar(good, w, ex_in, ex_out, files.FOUNDATION_NAME)
        loaders = {f"rltools {build.RLTOOLS_VERSION}": (build.rltools_headers(), False)}
        if a.px4_include:
            loaders[f"PX4's pin {(a.px4_commit or 'unknown')[:8]}"] = (a.px4_include, True)
        harnesses = {name: build.compile_harness(inc, posix) for name, (inc, posix) in loaders.items()}
        args = list(argv if argv is not None else sys.argv[1:])
        hidden = {str(a.px4_include): "RL_TOOLS_CHECKOUT/include", str(a.px4_blob): "PX4_BLOB/policy.tar"}
        args = [hidden.get(x, x) for x in args]  # paths on the machine that ran it: not recorded
        result = {
            "command": " ".join(["benchmarks/rltools_proof.py", *args]),
            "rltools_sdist": {"version": build.RLTOOLS_VERSION, "sha256": build.RLTOOLS_SDIST_SHA256},
            "px4_pin_commit": a.px4_commit,
            "machine": {"python": platform.python_version(), "numpy": np.__version__, "platform": platform.platform()},
            "policy": {
                "checkpoint_name": files.FOUNDATION_NAME,
                "source": "foundation-policy 1.0.2 (PyPI)",
                "sha256": digest,
                "bytes": good.stat().st_size,
                "parameters": rt.N_PARAMETERS,
                "our_replay_max_difference": rt.read_policy_tar(good).replay_max_difference,
                "low_order_byte_max_output_change": _low_byte_effect(good),
            },
            "loaders": {name: _loader(harness, good, work) for name, harness in harnesses.items()},
            "px4_blob": _px4_blob(a.px4_blob, w, harnesses) | {"commit": a.px4_blob_commit} if a.px4_blob else None,
            "our_reader_content_only": _our_reader(good, work, with_sha256=False),
            "our_reader_with_sha256": _our_reader(good, work, with_sha256=True),
        }
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"rltools_proof: wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
