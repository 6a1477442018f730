"""docs/architecture.md's import table is the law: every import between our packages in
src/quadpilot must be one the table allows, and every package must have a row."""

import ast
import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
SRC = ROOT / "src" / "quadpilot"


def allowed() -> dict[str, set[str]]:
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = doc.split("<!-- imports", 1)[1].split("<!-- /imports -->", 1)[0]
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = set(re.findall(r"`([a-z_]+)`", cells[2]))
    return rows


# Which package a file belongs to and which of ours it imports: the same reading the drawing in
# docs/architecture.md is made with (docs/architecture_drawing.py), so the table and the drawing
# cannot read the code differently.
_spec = importlib.util.spec_from_file_location("architecture_drawing", ROOT / "docs" / "architecture_drawing.py")
_drawing = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_drawing)
package_of = _drawing.package_of
imports = _drawing.imported_packages


def test_the_table_has_a_row_for_every_package_and_nothing_else():
    packages = {package_of(p) for p in SRC.rglob("*.py") if p.name != "__init__.py" or p.parent != SRC}
    packages.discard("__init__")
    assert set(allowed()) == packages


def test_every_import_between_packages_is_one_the_table_allows():
    rules = allowed()
    broken = []
    for path in sorted(SRC.rglob("*.py")):
        if path.parent == SRC and path.name == "__init__.py":
            continue
        pkg = package_of(path)
        for target in sorted(imports(path) - {pkg}):
            if target not in rules.get(pkg, set()):
                broken.append(f"{path.relative_to(ROOT)} imports quadpilot.{target}")
    assert not broken, "imports docs/architecture.md does not allow:\n" + "\n".join(broken)


def test_every_import_the_table_allows_is_used():
    """A permission no file uses is a door left open: the table says what the code does, no more."""
    used: dict[str, set[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        if not (path.parent == SRC and path.name == "__init__.py"):
            used.setdefault(package_of(path), set()).update(imports(path) - {package_of(path)})
    unused = [f"{pkg} may import {target}" for pkg, may in allowed().items() for target in sorted(may - used[pkg])]
    assert not unused, "the table allows imports no file makes (remove them):\n" + "\n".join(unused)


# --- the size of the rooms --------------------------------------------------------------------

MAX_LINES = 600
MAX_FOLDER_SHARE = 0.30


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def test_no_source_file_is_longer_than_600_lines():
    long = {str(p.relative_to(SRC)): n for p in sorted(SRC.rglob("*.py")) if (n := _lines(p)) > MAX_LINES}
    assert not long, f"split these modules (lines): {long}"


def test_no_folder_holds_more_than_30_percent_of_the_package():
    total = sum(_lines(p) for p in SRC.rglob("*.py"))
    shares = {
        d.name: sum(_lines(p) for p in d.rglob("*.py")) / total
        for d in SRC.iterdir()
        if d.is_dir() and d.name != "__pycache__"
    }
    big = {k: f"{v:.0%}" for k, v in shares.items() if v > MAX_FOLDER_SHARE}
    assert len(shares) >= 8 and not big, f"these folders hold more than {MAX_FOLDER_SHARE:.0%} of the lines: {big}"


def test_no_import_circle_between_the_modules_of_the_package():
    """Module-level graph over every module of src/quadpilot (imports inside functions included):
    a circle anywhere, within a package or across packages, fails."""
    modules = {
        ".".join(p.relative_to(SRC).with_suffix("").parts).removesuffix(".__init__"): p for p in SRC.rglob("*.py")
    }
    modules.pop("__init__", None)

    def targets(name: str, path: Path) -> set[str]:
        package = name.split(".")[:-1] if path.name != "__init__.py" else name.split(".")
        out = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[: len(package) - node.level + 1]
                    mod = [*base, *(node.module.split(".") if node.module else [])]
                elif (node.module or "").startswith("quadpilot."):
                    mod = node.module.split(".")[1:]
                else:
                    continue
                for a in node.names:  # `from .pkg import module` names a module, else the module itself
                    full = ".".join([*mod, a.name])
                    out.add(full if full in modules else ".".join(mod))
            elif isinstance(node, ast.Import):
                out.update(".".join(a.name.split(".")[1:]) for a in node.names if a.name.startswith("quadpilot."))
        return {t for t in out if t in modules and t != name and not name.startswith(t + ".")}

    graph = {name: targets(name, p) for name, p in modules.items()}
    state: dict[str, int] = {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                raise AssertionError(f"import circle: {' → '.join([*path, node, nxt])}")
            if nxt not in state:
                visit(nxt, [*path, node])
        state[node] = 2

    assert len(graph) > 80
    for name in sorted(graph):
        if name not in state:
            visit(name, [])


ISSUE_NUMBER = re.compile(r"(?i)(?<!github )\b(issue|task|ticket)\s*#?\d+|(?<![\w/])(?<!issue )#\d{1,4}\b")


def test_no_comment_or_docstring_cites_an_issue_number():
    """A reader of the code cannot look up our issue tracker: a comment cites what a reader can find
    (a paper, PX4's or MAVLink's docs, another project's GitHub issue by its repository's name)."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if ISSUE_NUMBER.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not found, "cites an issue number:\n" + "\n".join(found)


# A reader of the repository has only the repository: the documents the project was started from are
# cited by their own names (the course brief, the ENPM 667 project, a paper, a PX4 file), never by a
# path outside the repository or by the number they had where the project began.
OUTSIDE_CITATION = re.compile(r"(?i)\.\./shared\b|\bshared/(seeds|DESIGN)|\bDESIGN\.md\b|\bseed 00\d\b")
CITING_FILES = ("README.md", "docs", "src", "tests", "benchmarks", "models", "pyproject.toml")
TEXT_SUFFIXES = {".md", ".py", ".toml", ".txt", ".json", ".c", ".h", ".cpp"}


def outside_citations(root: Path) -> list[str]:
    found = []
    for name in CITING_FILES:
        top = root / name
        paths = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.suffix in TEXT_SUFFIXES)
        for path in paths:
            if "egg-info" in str(path) or path == Path(__file__):
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
                if OUTSIDE_CITATION.search(line):
                    found.append(f"{path.relative_to(root)}:{n}: {line.strip()[:100]}")
    return found


def test_no_file_cites_a_path_outside_the_repository_or_a_seed_by_number():
    found = outside_citations(ROOT)
    assert not found, "cites what a reader of the repository does not have:\n" + "\n".join(found)


def test_outside_citation_check_finds_planted_ones(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("as ../shared/DESIGN.md says\nfine\nSeed 001's table\n")
    (tmp_path / "README.md").write_text("see shared/seeds/000_x.txt\n")
    assert [f.split(":")[1] for f in outside_citations(tmp_path)] == ["1", "1", "3"]


def constants_defined_twice(root: Path) -> list[str]:
    """Module-level constants (UPPER_CASE = literal) defined with the same name and value in more than
    one module: the second is a copy that can drift from the first."""
    seen: dict[tuple[str, object], list[str]] = {}
    for path in sorted(root.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
            if not isinstance(node, (ast.Assign, ast.AnnAssign)) or not isinstance(node.value, ast.Constant):
                continue
            for t in targets:
                if isinstance(t, ast.Name) and t.id.isupper():
                    seen.setdefault((t.id, node.value.value), []).append(str(path.relative_to(root)))
    return [f"{name} = {value!r} in {', '.join(where)}" for (name, value), where in seen.items() if len(where) > 1]


def test_each_constant_is_defined_once():
    twice = constants_defined_twice(SRC)
    assert not twice, "defined more than once (import the first instead):\n" + "\n".join(twice)


def test_a_copied_constant_is_found(tmp_path):
    (tmp_path / "a.py").write_text("NUM_MOTORS = 4\nDT = 0.01\n")
    (tmp_path / "b.py").write_text("NUM_MOTORS = 4\nDT = 0.02\n")
    assert constants_defined_twice(tmp_path) == ["NUM_MOTORS = 4 in a.py, b.py"]


# --- the floors inside train ------------------------------------------------------------------


def train_floors() -> dict[str, int]:
    """docs/architecture.md's floor table of `train`: sub-package or top-level module → floor."""
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = doc.split("<!-- train-floors", 1)[1].split("<!-- /train-floors -->", 1)[0]
    floors = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].isdigit():
            floors.update(dict.fromkeys(re.findall(r"`([a-z_0-9]+)`", cells[1]), int(cells[0])))
    return floors


def train_imports(train: Path) -> list[tuple[str, str, str]]:
    """Every import between the parts of the package `train` (its sub-packages and top-level
    modules), at module level or inside a function: (file:line, importing part, imported part).
    A file's part is its first folder under `train`, or its own name at the top."""
    found = []
    for path in sorted(train.rglob("*.py")):
        rel = path.relative_to(train)
        if rel == Path("__init__.py"):
            continue  # the package itself: it registers the environments and imports nothing of ours
        part = rel.parts[0].removesuffix(".py")
        package = list(rel.parts[:-1])  # the importing file's package, as folders under train
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level:
                if node.level - 1 > len(package):
                    continue  # above train: another of our packages
                mod = [*package[: len(package) - node.level + 1], *(node.module.split(".") if node.module else [])]
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(f"quadpilot.{train.name}"):
                mod, names = node.module.split(".")[2:], [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                mods = [a.name.split(".")[2:] for a in node.names if a.name.startswith(f"quadpilot.{train.name}.")]
                found += [(f"{rel}:{node.lineno}", part, m[0]) for m in mods]
                continue
            else:
                continue
            targets = [mod[0]] if mod else names  # `from .. import cli` names the part itself
            found += [(f"{rel}:{node.lineno}", part, t) for t in targets if t != part]
    return found


def upward_imports(train: Path, floors: dict[str, int]) -> list[str]:
    """The imports inside `train` to a higher floor, and the parts the floor table does not place."""
    bad = []
    for where, part, target in train_imports(train):
        if part not in floors or target not in floors:
            bad.append(f"{where}: {part} → {target}: not in the floor table")
        elif floors[target] > floors[part]:
            bad.append(f"{where}: {part} (floor {floors[part]}) imports {target} (floor {floors[target]})")
    return bad


def test_the_floor_table_places_every_part_of_train():
    train = SRC / "train"
    parts = {p.name.removesuffix(".py") for p in train.iterdir() if p.suffix == ".py" or (p / "__init__.py").exists()}
    assert set(train_floors()) == parts - {"__init__"}


def test_imports_inside_train_go_down_or_sideways():
    bad = upward_imports(SRC / "train", train_floors())
    assert not bad, "imports docs/architecture.md's floors of train do not allow:\n" + "\n".join(bad)


def test_floor_check_finds_planted_ones(tmp_path):
    train = tmp_path / "train"
    for folder in ("envs", "runs", "ppo"):
        (train / folder).mkdir(parents=True)
        (train / folder / "__init__.py").write_text("")
    (train / "cli.py").write_text("from .runs import loop\nfrom .ppo import PPO\n")
    (train / "envs" / "batch.py").write_text("import numpy\n")
    (train / "ppo" / "__init__.py").write_text("from ..runs import trainer\nfrom . import config\n")
    (train / "runs" / "loop.py").write_text(
        "from ..envs import batch\n\n\ndef train():\n    from ..ppo import PPO\n    import quadpilot.train.cli\n"
    )
    (train / "runs" / "checkpoint.py").write_text(
        "from quadpilot.train import ppo\nfrom quadpilot.train.sac import SAC\n"
    )
    floors = {"cli": 3, "ppo": 2, "runs": 1, "envs": 0}
    assert upward_imports(train, floors) == [
        "runs/checkpoint.py:1: runs (floor 1) imports ppo (floor 2)",
        "runs/checkpoint.py:2: runs → sac: not in the floor table",
        "runs/loop.py:5: runs (floor 1) imports ppo (floor 2)",
        "runs/loop.py:6: runs (floor 1) imports cli (floor 3)",
    ]
