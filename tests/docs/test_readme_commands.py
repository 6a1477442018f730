"""README.md's commands run in order as written: every quad-train run writes a directory no earlier
command wrote (or, with --resume, one an earlier command did), and every path under runs/ a later
command reads is one an earlier command wrote (quad-train's run directory and policy.pt,
quad-export's output). Nothing is trained: the flags are read by quad-train's own parser."""

import re
import shlex
from pathlib import Path

ROOT = Path(__file__).parents[2]


def _commands(text: str) -> list[list[str]]:
    """The shell commands of README.md's fenced bash blocks, in order (`&&` chains split)."""
    out = []
    for block in re.findall(r"^```bash\n(.*?)^```", text, re.S | re.M):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            while words:
                cut = words.index("&&") if "&&" in words else len(words)
                out.append(words[:cut])
                words = words[cut + 1 :]
    return out


def _flag(words: list[str], *names: str) -> str | None:
    for i, w in enumerate(words[:-1]):
        if w in names:
            return words[i + 1]
    return None


def _train_out(words: list[str]) -> tuple[Path, bool] | None:
    """(the run directory, whether it is resumed) of one quad-train command; None for --help."""
    from quadpilot.train.algorithms import ALGORITHMS
    from quadpilot.train.cli import build_parser
    from quadpilot.train.runs.loop import default_out

    if "--help" in words:
        return None
    args = build_parser().parse_args(words)
    if args.out:
        return Path(args.out), args.resume
    seed = args.seed if args.seed is not None else 0
    if args.algo == "sb3":
        return Path(f"runs/{args.task}-sb3-seed{seed}"), args.resume
    return default_out(args.task, ALGORITHMS[args.algo], seed), args.resume


def walk(text: str) -> list[str]:
    """What goes wrong when README.md's commands are run in order, as one line each."""
    made: set[Path] = set()
    problems = []
    for words in _commands(text):
        tool = Path(words[0]).name
        written = None
        if tool == "quad-train":
            got = _train_out(words[1:])
            if got is None:
                continue
            out, resumed = got
            if resumed and out not in made:
                problems.append(f"{shlex.join(words)}: resumes {out}, which no earlier command wrote")
            if not resumed and out in made:
                problems.append(f"{shlex.join(words)}: refused, {out} exists (an earlier command wrote it)")
            made |= {out, out / "policy.pt"}
            written = str(out)
        elif tool == "quad-export":
            ckpt = Path(next(w for w in words[1:] if w.endswith(".pt")))
            written = _flag(words, "-o", "--output")
            fmt = _flag(words, "--format") or "onnx"
            default = ckpt.with_suffix(".onnx") if fmt == "onnx" else ckpt.parent / "policy.tar"
            made.add(Path(written) if written else default)
        for w in words[1:]:
            if w.startswith("runs/") and w != written and Path(w) not in made:
                problems.append(f"{shlex.join(words)}: reads {w}, which no earlier command wrote")
    return problems


def test_readme_commands_run_in_order_as_written():
    assert walk((ROOT / "README.md").read_text(encoding="utf-8")) == []


def test_the_walk_finds_a_refused_run_and_a_path_never_written():
    text = (
        "```bash\n.venv/bin/quad-train --task hover\n.venv/bin/quad-train --task hover --preset seed001\n"
        ".venv/bin/quad-export runs/hover/policy.pt\n.venv/bin/quad-train --task hover --out runs/x --resume\n```\n"
    )
    problems = walk(text)
    assert len(problems) == 3, problems
    assert "refused, runs/hover-seed0 exists" in problems[0]
    assert "reads runs/hover/policy.pt" in problems[1] and "resumes runs/x" in problems[2]
