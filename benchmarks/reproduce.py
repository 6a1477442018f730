"""Compare a shipped model with reruns of its recorded command, and keep the comparison as data
(docs/testing.md, "Reproducing the shipped models").

    .venv/bin/quad-train --task hover --out /tmp/rerun-head          # the command in models/hover/config.json
    .venv/bin/python benchmarks/reproduce.py models/hover head=/tmp/rerun-head --out docs/testing/reproduce.json

For each rerun: whether every tensor of the policy (`model`, `obs_rms`) equals the shipped one bit
for bit, how many differ and by how much at most, the rerun's evaluation next to the shipped one,
and, between reruns, whether they equal each other. The CPU of this machine is recorded (model
name, family/model/stepping, a digest of the flag set), since torch's kernels depend on it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
from pathlib import Path

EVAL_KEYS = ("success_rate", "mean_error_last_window_m", "first_success", "train_time_s")


def _tensors(path: Path) -> dict:
    import torch

    data = torch.load(path, weights_only=True, map_location="cpu")
    out = {f"model/{k}": v for k, v in data["model"].items()}
    out.update({f"obs_rms/{k}": v for k, v in data["obs_rms"].items() if torch.is_tensor(v)})
    return out


def differences(a: Path, b: Path) -> dict:
    import torch

    ta, tb = _tensors(a), _tensors(b)
    diffs = {
        k: float((v.double() - tb[k].double()).abs().max())
        for k, v in ta.items()
        if k not in tb or v.shape != tb[k].shape or not torch.equal(v, tb[k])
    }
    return {"tensors": len(ta), "differing": len(diffs), "max_abs_difference": max(diffs.values(), default=0.0)}


def cpu() -> dict:
    info: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            key = key.strip()
            if key in ("vendor_id", "model name", "cpu family", "model", "stepping", "flags") and key not in info:
                info[key] = value.strip()
    except OSError:
        return {"processor": platform.processor()}
    flags = info.pop("flags", "")
    info["flags_sha256"] = hashlib.sha256(" ".join(sorted(flags.split())).encode()).hexdigest()[:16]
    info["avx512f"] = "avx512f" in flags.split()
    info["amx_tile"] = "amx_tile" in flags.split()
    return info


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path, help="the shipped model directory")
    p.add_argument("reruns", nargs="+", metavar="NAME=RUN_DIR")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    reruns = {}
    for item in args.reruns:
        name, sep, path = item.partition("=")
        if not sep:
            p.error(f"expected NAME=RUN_DIR, got {item!r}")
        reruns[name] = Path(path)
    shipped_eval = json.loads((args.model / "eval.json").read_text())
    data = {
        "model": str(args.model),
        "command": json.loads((args.model / "config.json").read_text())["command"],
        "shipped_eval": {k: shipped_eval.get(k) for k in EVAL_KEYS},
        "cpu": cpu(),
        "reruns": {},
    }
    names = list(reruns)
    for name, run in reruns.items():
        ev = json.loads((run / "eval.json").read_text())
        entry = {
            "command": json.loads((run / "config.json").read_text())["command"],
            "against_shipped": differences(args.model / "policy.pt", run / "policy.pt"),
            "eval": {k: ev.get(k) for k in EVAL_KEYS},
        }
        entry["identical_to_shipped"] = entry["against_shipped"]["differing"] == 0
        for other in names[: names.index(name)]:
            entry[f"against_{other}"] = differences(reruns[other] / "policy.pt", run / "policy.pt")
        data["reruns"][name] = entry
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    for name, e in data["reruns"].items():
        print(f"{name}: {e['against_shipped']['differing']} of {e['against_shipped']['tensors']} tensors differ")
    return 0


if __name__ == "__main__":
    sys.exit(main())
