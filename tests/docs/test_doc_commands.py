"""Every ```bash block of README.md and docs/*.md runs, as written, under QUADPILOT_DOCS_QUICK=1
(console.docs_quick: a few training steps, one episode), and fails the test run when it fails.

Sybil (sybil.parsers.markdown) finds the blocks and the skip directives; nothing here parses Markdown.
A block that needs hardware, a person, a download or hours is marked in the Markdown just before it:

    <!-- skip: next "hardware: a ground station (QGroundControl) on UDP 14550" -->

and is reported by pytest as skipped with that reason. `<!-- invisible-code-block: bash ... -->`
runs setup the reader has done already (the quick start's training run a later block exports).

Each document's blocks run in order in one scratch copy of the repository's tracked files (a temp
dir; nothing is written into the tree), with `.venv` a link to this interpreter's environment and
PYTHONPATH the copy's `src`, so `.venv/bin/quad-train` runs the code under test (`.venv/bin` is first
on PATH too, as in an activated environment, for the blocks that write `quad-train`). Each block runs
with `bash -eo pipefail`: its first failing command fails it. docs/testing.md says how to mark a
block."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import unittest
from pathlib import Path

import pytest
from sybil import Sybil
from sybil.example import Example
from sybil.parsers.markdown import CodeBlockParser, SkipParser

ROOT = Path(__file__).resolve().parents[2]
DOCS = ["README.md", *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md"))]
BLOCK_TIMEOUT_S = 300


def _sybil() -> Sybil:
    return Sybil(parsers=[CodeBlockParser("bash", evaluator=_run_block), SkipParser()])


def _examples(doc: str) -> list[Example]:
    return list(_sybil().parse(ROOT / doc))


def _is_block(example: Example) -> bool:
    return example.region.evaluator is _run_block


def _cases() -> list:
    return [pytest.param(doc, ex.line, id=f"{doc}:{ex.line}") for doc in DOCS for ex in _examples(doc) if _is_block(ex)]


def _tracked_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [f for f in out.decode().split("\0") if f]


def scratch_copy(dest: Path) -> Path:
    """A copy of the tracked files under `dest` (as they are in the work tree), with `.venv` a link to
    this interpreter's environment."""
    for rel in _tracked_files():
        src = ROOT / rel
        if not src.exists() and not src.is_symlink():  # deleted in the work tree, not yet committed
            continue
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            target.symlink_to(os.readlink(src))
        else:
            shutil.copy2(src, target)
    (dest / ".venv").symlink_to(sys.prefix, target_is_directory=True)
    return dest


def _run_block(example: Example) -> str | None:
    """Sybil's evaluator of a bash block: runs it when it is the one this test asked for, else does
    nothing (a later block's test walks the earlier ones only for their skip directives)."""
    ns = example.namespace
    if example.line not in ns["run_lines"]:
        return None
    env = dict(os.environ)
    env["QUADPILOT_DOCS_QUICK"] = "1"
    env["PYTHONPATH"] = os.pathsep.join([str(ns["cwd"] / "src"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["MPLBACKEND"] = "Agg"
    env["PATH"] = os.pathsep.join([str(ns["cwd"] / ".venv" / "bin"), env.get("PATH", "")])  # as if activated
    try:
        done = subprocess.run(
            ["bash", "-eo", "pipefail", "-c", example.parsed],
            cwd=ns["cwd"],
            env=env,
            capture_output=True,
            text=True,
            timeout=BLOCK_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:
        return (
            f"{example.path}:{example.line}: the block ran longer than {BLOCK_TIMEOUT_S} s under QUADPILOT_DOCS_QUICK"
        )
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).splitlines()[-30:])
        return f"{example.path}:{example.line}: the block exited with {done.returncode}\n{tail}"
    return None


_SCRATCH: dict[str, Path] = {}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """One scratch copy of the repository per document, shared by its blocks in order; afterwards the
    work tree's `git status` is what it was before (no block wrote into it)."""
    before = _git_status()

    def get(doc: str) -> tuple[Path, bool]:
        fresh = doc not in _SCRATCH
        if fresh:
            _SCRATCH[doc] = scratch_copy(tmp_path_factory.mktemp("doc-" + Path(doc).stem))
        return _SCRATCH[doc], fresh

    yield get
    _SCRATCH.clear()
    _SETUP_DONE.clear()
    assert _git_status() == before, "a documented command wrote into the repository's work tree"


def _git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True).stdout


@pytest.mark.parametrize(("doc", "line"), _cases())
def test_doc_block_runs(doc, line, scratch):
    """The block at `doc:line` runs (or is skipped by name) in its document's scratch copy, after the
    blocks before it (pytest runs them in order). Run alone (`-k`), it first runs the document's
    invisible setup blocks before it."""
    cwd, _ = scratch(doc)
    examples = _examples(doc)
    done = _SETUP_DONE.setdefault(cwd, set())
    setup = {ex.line for ex in examples if _is_block(ex) and ex.line < line and _invisible(ex)} - done
    for ex in examples:
        ex.namespace["cwd"] = cwd
        ex.namespace["run_lines"] = setup | {line}
    for ex in examples:
        if ex.line > line:
            break
        if not _is_block(ex):
            ex.evaluate()  # a skip directive
            continue
        try:
            ex.evaluate()
        except unittest.SkipTest as e:  # an earlier block's skip is that block's, not this one's
            if ex.line == line:
                pytest.skip(f"{doc}:{line}: {e}")
        if _invisible(ex) and (ex.line in setup or ex.line == line):
            done.add(ex.line)


_SETUP_DONE: dict[Path, set[int]] = {}


def _invisible(example: Example) -> bool:
    text = example.document.text
    return text[example.region.start : example.region.start + 4] == "<!--"


def test_every_skip_says_why():
    """A skip directive names its reason (pytest prints it); a bare `skip: next` would pass silently."""
    bare = [
        f"{doc}:{ex.line}"
        for doc in DOCS
        for ex in _examples(doc)
        if isinstance(ex.region.evaluator, type(SkipParser().skipper)) and not (ex.parsed[1] or "").strip()
    ]
    assert not bare, f"skip directives without a reason: {bare}"


SKIP_KINDS = (
    "setup",
    "download",
    "hardware",
    "person",
    "two processes",
    "recursive",
    "git history",
    "placeholders",
    "long",
)


def test_every_skip_reason_starts_with_its_kind():
    """docs/testing.md's rule: a skip's reason starts with one of its kinds and a colon, so a reader
    (and pytest's report) can tell a block that needs a person from one nobody shortened yet."""
    off = [
        f"{doc}:{ex.line}: {ex.parsed[1]}"
        for doc in DOCS
        for ex in _examples(doc)
        if isinstance(ex.region.evaluator, type(SkipParser().skipper))
        and ex.parsed[0] == "next"
        and not (ex.parsed[1] or "").strip().strip("\"'").startswith(tuple(f"{k}:" for k in SKIP_KINDS))
    ]
    assert not off, "skip reasons that do not start with a kind of docs/testing.md:\n" + "\n".join(off)


def test_a_renamed_flag_in_a_block_fails(tmp_path):
    """The check itself: README's quick-start export with a flag that does not exist fails."""
    doc = tmp_path / "doc.md"
    doc.write_text("```bash\n.venv/bin/quad-export --no-such-flag models/hover/policy.pt -o x.onnx\n```\n")
    (tmp_path / ".venv").symlink_to(sys.prefix, target_is_directory=True)
    (tmp_path / "models").symlink_to(ROOT / "models", target_is_directory=True)  # read only: refused first
    (tmp_path / "src").symlink_to(ROOT / "src", target_is_directory=True)
    (ex,) = list(_sybil().parse(doc))
    ex.namespace["cwd"] = tmp_path
    ex.namespace["run_lines"] = {ex.line}
    with pytest.raises(Exception, match="exited with 2"):
        ex.evaluate()


def test_the_quick_switch_caps_sizes_only_when_set(monkeypatch):
    """console.quick: the full size without the switch; under it the smaller of the two, and the quick
    size for a size left to its default (None). "0" and "" leave the switch off."""
    from quadpilot.console import QUICK_ENV, docs_quick, quick

    for off in ("", "0", "false"):
        monkeypatch.setenv(QUICK_ENV, off)
        assert not docs_quick() and quick(1_000_000, 2048) == 1_000_000 and quick(None, 2048) is None
    monkeypatch.setenv(QUICK_ENV, "1")
    assert docs_quick()
    assert (quick(1_000_000, 2048), quick(100, 2048), quick(None, 1)) == (2048, 100, 1)
