"""Mutation-testing results as data: read mutmut's own result files and write docs/testing/mutmut.json,
or print the Markdown table of docs/testing.md from that JSON.

    .venv/bin/mutmut run --max-children 2 "quadpilot.train.ppo.gae.*"          # measure (docs/testing.md)
    .venv/bin/python benchmarks/report_mutmut.py record mutants/ docs/testing/mutmut.json gae
    .venv/bin/python benchmarks/report_mutmut.py table docs/testing/mutmut.json

mutmut 3 keeps one `<file>.py.meta` per mutated file under `mutants/src/`, whose `exit_code_by_key`
maps each mutant's name to the exit code of the test run against it; `mutmut.stats.status_by_exit_code`
turns that into killed / survived / timeout / no tests / not checked. `record` counts the mutants of
the named modules (each selected by the same name glob as its `mutmut run` command) and replaces
those modules' entries in the JSON, keeping the others; a module with a mutant not yet checked is
refused, so a partial run is never recorded as a score.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import fnmatch
import json
import platform
import sys
from importlib import metadata
from pathlib import Path

# label → (file under src/quadpilot, the mutant-name globs that select its mutants: the arguments of
# the `mutmut run` command that measures it)
MODULES = {
    "gae": ("train/ppo/gae.py", "quadpilot.train.ppo.gae.*"),
    "ppo_update": (
        "train/ppo/__init__.py",
        ("quadpilot.train.ppo.xǁPPOǁupdate__mutmut_*", "quadpilot.train.ppo.xǁ*PPOǁ_gradient_step__mutmut_*"),
    ),
    "numpy_ppo": ("train/ppo/numpy_ppo.py", "quadpilot.train.ppo.numpy_ppo.*"),
    "dynamics": ("core/dynamics.py", "quadpilot.core.dynamics.*"),
    "stepper": (
        "core/dynamics.py",
        ("quadpilot.core.dynamics.xǁStepperǁ*", "quadpilot.core.dynamics.xǁ_StepperConstantsǁ*"),
    ),
    "mixer": ("core/mixer.py", "quadpilot.core.mixer.*"),
    "core_frames": ("core/frames.py", "quadpilot.core.frames.*"),
    "normalize": ("core/normalize.py", "quadpilot.core.normalize.*"),
    "reward": ("core/reward.py", "quadpilot.core.reward.*"),
    "safety": ("runtime/safety.py", "quadpilot.runtime.safety.*"),
    "wire": ("link/wire.py", "quadpilot.link.wire.*"),
    "link_frames": ("link/frames.py", "quadpilot.link.frames.*"),
}
LABELS = {
    "gae": "`train/ppo/gae.py`",
    "ppo_update": "`train/ppo/__init__.py`, `PPO.update` and the variants' `_gradient_step` (the losses)",
    "numpy_ppo": "`train/ppo/numpy_ppo.py` (the update every MLP trains with)",
    "dynamics": "`core/dynamics.py`",
    "stepper": "`core/dynamics.py`, the in-place `Stepper` and its constants",
    "mixer": "`core/mixer.py`",
    "core_frames": "`core/frames.py`",
    "normalize": "`core/normalize.py`",
    "reward": "`core/reward.py`",
    "safety": "`runtime/safety.py`",
    "wire": "`link/wire.py`",
    "link_frames": "`link/frames.py`",
}
STATUSES = ("killed", "survived", "timeout", "no tests", "not checked", "suspicious", "segfault", "skipped")


def count(mutants: Path, label: str) -> dict:
    """One module's result from mutmut's meta file: counts per status, score, survivors."""
    from mutmut.stats import status_by_exit_code

    rel, globs = MODULES[label]
    globs = (globs,) if isinstance(globs, str) else globs
    glob = " ".join(globs)
    meta = mutants / "src" / "quadpilot" / (rel + ".meta")
    try:
        codes = json.loads(meta.read_text())["exit_code_by_key"]
    except (OSError, json.JSONDecodeError, KeyError) as e:
        raise SystemExit(f"report_mutmut: cannot read mutmut's results {meta}: {e}") from None
    status = {k: status_by_exit_code[v] for k, v in codes.items() if any(fnmatch.fnmatchcase(k, g) for g in globs)}
    if not status:
        raise SystemExit(f"report_mutmut: no mutant of {label} ({glob}) in {meta}")
    unchecked = sorted(k for k, s in status.items() if s == "not checked")
    if unchecked:
        raise SystemExit(
            f"report_mutmut: {len(unchecked)} mutants of {label} not checked yet (e.g. {unchecked[0]}); "
            f"run `mutmut run --max-children 2 {' '.join(repr(g) for g in globs)}` first"
        )
    counts = {s: sum(1 for v in status.values() if v == s) for s in STATUSES}
    counts = {s: n for s, n in counts.items() if n or s in ("killed", "survived", "timeout")}
    total = len(status)
    measured = _dt.datetime.fromtimestamp(meta.stat().st_mtime, _dt.timezone.utc).isoformat(timespec="seconds")
    return {
        "measured": measured,  # when mutmut last wrote its result file
        "file": f"src/quadpilot/{rel}",
        "selection": glob,
        "command": "mutmut run --max-children 2 " + " ".join(f'"{g}"' for g in globs),
        "mutants": total,
        "counts": counts,
        "score": (counts["killed"] + counts["timeout"]) / total,
        "survivors": sorted((k for k, s in status.items() if s == "survived"), key=_natural),
    }


def _natural(name: str):
    head, _, n = name.rpartition("_")
    return (head, int(n) if n.isdigit() else 0)


def record(mutants: Path, out: Path, labels: list[str], commit: str | None = None) -> dict:
    data = json.loads(out.read_text()) if out.exists() else {"modules": {}}
    for label in labels:
        entry = count(mutants, label)
        if commit:
            entry["commit"] = commit  # the commit whose code mutmut mutated
        entry["mutmut"] = metadata.version("mutmut")
        entry["python"] = platform.python_version()
        data["modules"][label] = entry
    data["modules"] = {k: data["modules"][k] for k in MODULES if k in data["modules"]}
    data["score_definition"] = "(killed + timeout) / mutants"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
    return data


def table(data: dict) -> str:
    lines = [
        "| module | mutants | killed | survived | timeout | score | measured | command |",
        "|---|---:|---:|---:|---:|---:|---|---|",
    ]
    for label, m in data["modules"].items():
        c = m["counts"]
        when = m["measured"][:10] + (f", {m['commit'][:7]}" if m.get("commit") else "")
        lines.append(
            f"| {LABELS[label]} | {m['mutants']} | {c['killed']} | {c['survived']} | {c['timeout']} | "
            f"{100 * m['score']:.1f} % | {when} | `{m['command']}` |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="count mutmut's results of MODULE... into the JSON")
    r.add_argument("mutants", type=Path, help="mutmut's directory (mutants/)")
    r.add_argument("json", type=Path)
    r.add_argument("modules", nargs="+", choices=sorted(MODULES))
    r.add_argument("--commit", help="the commit of the code mutmut ran on (shown in the table)")
    t = sub.add_parser("table", help="the Markdown table of docs/testing.md")
    t.add_argument("json", type=Path)
    args = p.parse_args(argv)
    if args.cmd == "record":
        data = record(args.mutants, args.json, args.modules, args.commit)
    else:
        try:
            data = json.loads(args.json.read_text())
        except (OSError, json.JSONDecodeError) as e:
            print(f"report_mutmut: cannot read {args.json}: {e}", file=sys.stderr)
            return 1
    print(table(data), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
