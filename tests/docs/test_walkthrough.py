"""docs/ppo_walkthrough.md links each equation to the code that implements it, as
`path/to/file.py::function` or `path/to/file.py::Class.method`. Every such reference must still
point at a file that exists and a name defined in it, so renaming a function without updating the
walkthrough fails here. Read with `ast` only: nothing is imported, no torch, milliseconds."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "ppo_walkthrough.md"

_PATH = r"(?:src|tests|benchmarks|docs)/[\w./-]*?\.py"
FILE_RE = re.compile(rf"(?<![\w./-])({_PATH})(?![\w])")
REF_RE = re.compile(rf"(?<![\w./-])({_PATH})::([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)")

# The core components the walkthrough must explain.
REQUIRED_REFS = {
    "src/quadpilot/train/ppo/gae.py::compute_gae",
    "src/quadpilot/train/ppo/__init__.py::FeedForwardPPO.collect",
    "src/quadpilot/train/ppo/__init__.py::PPO.update",
    "src/quadpilot/train/ppo/config.py::PPOConfig",
    "src/quadpilot/train/networks/__init__.py::ActorCritic",
    "src/quadpilot/train/networks/__init__.py::ActorCritic.distribution",
    "src/quadpilot/core/normalize.py::RunningMeanStd",
}
# Every file the walkthrough is asked to cover must be referenced at least once.
REQUIRED_FILES = {
    *(f"src/quadpilot/train/{n}.py" for n in ("networks/__init__", "ppo/gae", "ppo/__init__", "envs/__init__")),
    *(f"src/quadpilot/train/{n}.py" for n in ("runs/checkpoint", "runs/runlog", "envs/evaluate", "envs/curriculum")),
    *(f"src/quadpilot/core/{n}.py" for n in ("dynamics", "observation", "reward", "normalize")),
}
# metrics.csv columns the diagnosis section reads; each must be a real column (runlog.COLUMNS).
DIAGNOSIS_COLUMNS = (
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "grad_norm",
    "lr",
    "ep_return",
    "ep_length",
    "success_rate",
    "nonfinite_skipped",
    "eval_success_rate",
    "eval_error_m",
)


def references(text: str) -> set[tuple[str, str]]:
    """(file, dotted name) for every `file.py::name` in `text`."""
    return set(REF_RE.findall(text))


def _defined_here(body: list[ast.stmt], name: str) -> ast.AST | None:
    """The statement of `body` that defines `name`: def, class, or an assignment to it."""
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
            return node
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        for t in targets:
            names = t.elts if isinstance(t, ast.Tuple) else [t]
            if any(isinstance(n, ast.Name) and n.id == name for n in names):
                return node
    return None


def is_defined(source: str, dotted: str) -> bool:
    """Whether `dotted` (`func`, `Class`, `Class.method`, `Class.field`) is defined in `source`."""
    body: list[ast.stmt] = ast.parse(source).body
    for part in dotted.split("."):
        node = _defined_here(body, part)
        if node is None:
            return False
        body = node.body if isinstance(node, ast.ClassDef) else []
    return True


def missing(refs: set[tuple[str, str]], root: Path) -> list[str]:
    """The references of `refs` whose file does not exist or does not define the name."""
    out, sources = [], {}
    for path, name in sorted(refs):
        f = root / path
        if not f.is_file():
            out.append(f"{path}::{name} (no such file)")
            continue
        if path not in sources:
            sources[path] = f.read_text(encoding="utf-8")
        if not is_defined(sources[path], name):
            out.append(f"{path}::{name} (not defined in {path})")
    return out


def doc_text() -> str:
    assert DOC.is_file(), f"{DOC} is missing"
    return DOC.read_text(encoding="utf-8")


def test_every_named_file_exists():
    files = set(FILE_RE.findall(doc_text()))
    assert files, "the walkthrough names no source file"
    gone = sorted(f for f in files if not (ROOT / f).is_file())
    assert not gone, f"docs/ppo_walkthrough.md names files that do not exist: {gone}"


def test_every_named_function_class_and_method_is_defined():
    refs = references(doc_text())
    assert len(refs) >= 20, f"expected the walkthrough to link its equations to code, found {len(refs)} references"
    bad = missing(refs, ROOT)
    assert not bad, "docs/ppo_walkthrough.md points at code that no longer exists (renamed?): " + "; ".join(bad)


def test_the_core_components_are_named():
    text = doc_text()
    named = {f"{p}::{n}" for p, n in references(text)}
    assert REQUIRED_REFS <= named, f"the walkthrough does not name {sorted(REQUIRED_REFS - named)}"
    files = set(FILE_RE.findall(text))
    assert REQUIRED_FILES <= files, f"the walkthrough does not cover {sorted(REQUIRED_FILES - files)}"


def test_the_metrics_columns_the_diagnosis_reads_exist():
    tree = ast.parse((ROOT / "src/quadpilot/train/runs/runlog.py").read_text(encoding="utf-8"))
    node = _defined_here(tree.body, "COLUMNS")
    assert isinstance(node, ast.Assign), "runlog.COLUMNS is no longer a plain assignment"
    columns = set(ast.literal_eval(node.value))
    text = doc_text()
    unknown = [c for c in DIAGNOSIS_COLUMNS if c not in columns]
    assert not unknown, f"metrics.csv has no column {unknown}; update the walkthrough's diagnosis section"
    unnamed = [c for c in DIAGNOSIS_COLUMNS if f"`{c}`" not in text]
    assert not unnamed, f"the walkthrough does not name the metrics.csv columns {unnamed}"


def test_the_checker_notices_a_rename(tmp_path):
    """The checks above would catch `compute_gae` or `PPO.update` being renamed."""
    src = tmp_path / "src" / "m.py"
    src.parent.mkdir()
    src.write_text(
        "def compute_gae():\n    pass\n\nclass PPO:\n    lr: float = 1.0\n\n    def update(self):\n        pass\n"
    )
    text = "see `src/m.py::compute_gae`, `src/m.py::PPO.update`, `src/m.py::PPO.lr` and `src/m.py::PPO`."
    refs = references(text)
    assert refs == {
        ("src/m.py", "compute_gae"),
        ("src/m.py", "PPO.update"),
        ("src/m.py", "PPO.lr"),
        ("src/m.py", "PPO"),
    }
    assert missing(refs, tmp_path) == []
    src.write_text("def compute_advantages():\n    pass\n\nclass PPO:\n    def step(self):\n        pass\n")
    assert missing(refs, tmp_path) == [
        "src/m.py::PPO.lr (not defined in src/m.py)",
        "src/m.py::PPO.update (not defined in src/m.py)",
        "src/m.py::compute_gae (not defined in src/m.py)",
    ]
    assert missing({("src/gone.py", "f")}, tmp_path) == ["src/gone.py::f (no such file)"]


def _ppo_defaults() -> dict[str, object]:
    """quad-train's PPO defaults, read from the source with ast: PPOConfig's field defaults with the
    `fast` preset's on top."""
    tree = ast.parse((ROOT / "src/quadpilot/train/ppo/config.py").read_text(encoding="utf-8"))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "PPOConfig")
    fields = {
        s.target.id: ast.literal_eval(s.value)
        for s in cls.body
        if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name) and s.value is not None
    }
    presets = next(
        n.value for n in tree.body if isinstance(n, ast.AnnAssign) and getattr(n.target, "id", "") == "PRESETS"
    )
    fast = ast.literal_eval(presets)["fast"]  # what quad-train trains with: the fields, then the preset's
    assert set(fast) <= set(fields), (
        f"the fast preset sets what PPOConfig does not have: {sorted(set(fast) - set(fields))}"
    )
    return {**fields, **fast}


def _cell_matches(text: str, value: object) -> bool:
    text = text.strip().replace("−", "-")
    if isinstance(value, bool):
        return text == ("on" if value else "off")
    if value is None:
        return text == "None"
    if isinstance(value, (int, float)):
        try:
            return float(text.replace(",", "")) == float(value)
        except ValueError:
            return False
    return str(value) in text  # a schedule's name ("linear to 0")


def defaults_table_mismatches(doc: str, defaults: dict[str, object]) -> list[str]:
    """Rows of section 6's table whose 'default' column is not the code's default."""
    section = doc.split("## 6. The PPO update", 1)[1].split("Per minibatch", 1)[0]
    wrong = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 4 or "PPOConfig." not in cells[1]:
            continue
        names = re.findall(r"PPOConfig\.(\w+)", cells[1])
        values = [v.strip() for v in cells[2].split(",")] if len(names) > 1 else [cells[2]]
        for name, text in zip(names, values, strict=True):
            if not _cell_matches(text, defaults[name]):
                wrong.append(f"{name}: the walkthrough says {text!r}, the code's default is {defaults[name]!r}")
    k = re.search(r"K = `epochs` = (\d+) passes", section)
    if k is None or int(k.group(1)) != defaults["epochs"]:
        wrong.append(f"the prose's K is {k and k.group(1)}, epochs is {defaults['epochs']}")
    return wrong


def test_the_walkthrough_takes_its_ppo_defaults_from_the_code():
    assert not defaults_table_mismatches(DOC.read_text(encoding="utf-8"), _ppo_defaults())


def test_a_changed_default_is_caught():
    doc, defaults = DOC.read_text(encoding="utf-8"), _ppo_defaults()
    assert defaults_table_mismatches(doc, {**defaults, "epochs": 10}) == [
        "epochs: the walkthrough says '8', the code's default is 10",
        "the prose's K is 8, epochs is 10",
    ]
    assert len(defaults_table_mismatches(doc, {**defaults, "lr": 3e-4, "normalize_obs": True})) == 2
