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


def module_files(root: Path) -> dict[str, Path]:
    """{dotted name below `root` (`viz.video`, `viz` for viz/__init__.py): file}, the root's own
    __init__.py left out."""
    modules = {
        ".".join(p.relative_to(root).with_suffix("").parts).removesuffix(".__init__"): p for p in root.rglob("*.py")
    }
    modules.pop("__init__", None)
    return modules


def from_import_module(node: ast.ImportFrom, package: list[str], top: str = "quadpilot") -> list[str] | None:
    """The module a `from … import` statement reads from, as its parts below the package `top`
    ("quadpilot", or "quadpilot.train" for a sub-package): a relative import resolved against
    `package`, the importing module's package as parts below `top`. None for a module outside `top`."""
    if node.level:
        if node.level - 1 > len(package):
            return None  # above `top`
        return [*package[: len(package) - node.level + 1], *(node.module.split(".") if node.module else [])]
    if node.module == top or (node.module or "").startswith(f"{top}."):
        return node.module.split(".")[len(top.split(".")) :]
    return None


def test_no_import_circle_between_the_modules_of_the_package():
    """Module-level graph over every module of src/quadpilot (imports inside functions included):
    a circle anywhere, within a package or across packages, fails."""
    modules = module_files(SRC)

    def targets(name: str, path: Path) -> set[str]:
        package = name.split(".")[:-1] if path.name != "__init__.py" else name.split(".")
        out = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if (mod := from_import_module(node, package)) is None:
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


# --- private names stay home --------------------------------------------------------------------


def _private(name: str) -> bool:
    """`_x` and `__x` are private to their module; `__x__` (a dunder) and `_` are not."""
    return name.startswith("_") and len(name) > 1 and not (name.startswith("__") and name.endswith("__"))


def _private_members(tree: ast.AST) -> set[str]:
    """The private names a module's classes define: methods, class attributes, `self._x = ...`."""
    out = set()
    for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
        for node in ast.walk(cls):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node is not cls:
                out.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                out.add(node.id)  # class attributes (and a method's locals: harmless)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                    out.add(node.attr)
    return {n for n in out if _private(n)}


def _dotted(expr: ast.AST, aliases: dict[str, str], top: str) -> str | None:
    """`a.b.c` with its head read through `aliases` (a name bound to one of our modules), or with
    `top` itself as its head (`import quadpilot.a.m` binds `quadpilot`); else None."""
    if isinstance(expr, ast.Name):
        return aliases.get(expr.id, top if expr.id == top else None)
    if isinstance(expr, ast.Attribute) and (head := _dotted(expr.value, aliases, top)) is not None:
        return f"{head}.{expr.attr}"
    return None


def _attribute_read(node: ast.AST) -> tuple[ast.AST, str] | None:
    """(object, name) of `obj.name` or of `getattr(obj, "name")` and its kin."""
    if isinstance(node, ast.Attribute):
        return node.value, node.attr
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
        and len(node.args) >= 2
        and isinstance(node.args[1], ast.Constant)
        and isinstance(node.args[1].value, str)
    ):
        return node.args[0], node.args[1].value
    return None


def _own(obj: ast.AST) -> bool:
    """`self`, `cls` or `super()`: the class's own members."""
    if isinstance(obj, ast.Call) and isinstance(obj.func, ast.Name):
        return obj.func.id == "super"
    return isinstance(obj, ast.Name) and obj.id in ("self", "cls")


def private_names_used_across_modules(root: Path) -> list[str]:
    """Each use, in a module of `root` (a package folder: its name is the top of absolute imports), of
    a private name that lives in another of its modules: `from .m import _x`, `m._x` through a module
    `m` imported by any name (`import a.m as m`, `from . import m`, `a.m._x`), and `obj._x` on an
    object when `_x` is a private member (a method, a class attribute, or an attribute a method sets
    as `self._x`) of a class in another module and of none in this one; `getattr(obj, "_x")` and its
    kin count as `obj._x`. A private module may be imported by the modules of its own package.

    What `ast` cannot see, so this does not: the type of an object, so a private member with the same
    name in this module and in another is taken as this module's own; `self._x`, `cls._x` and
    `super()._x`, which are taken as the class's own even where a base class in another module
    defines `_x`; a local name that shadows an imported module; a name reached by a string built at
    run time."""
    top = root.name
    modules = module_files(root)
    trees = {name: ast.parse(p.read_text(encoding="utf-8")) for name, p in modules.items()}
    owned = {name: _private_members(tree) for name, tree in trees.items()}
    found = set()
    for name, tree in trees.items():
        where = str(modules[name].relative_to(root))
        package = name.split(".") if modules[name].name == "__init__.py" else name.split(".")[:-1]
        others = set().union(*(m for n, m in owned.items() if n != name)) - owned[name]
        aliases: dict[str, str] = {}  # a local name → the module of ours it stands for
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.asname and (mod := a.name.removeprefix(f"{top}.")) in modules:
                        aliases[a.asname] = mod
            elif isinstance(node, ast.ImportFrom):
                if (parts := from_import_module(node, package, top)) is None:
                    continue
                mod = ".".join(parts)
                for a in node.names:
                    full = f"{mod}.{a.name}".lstrip(".")
                    if full in modules:
                        aliases[a.asname or a.name] = full
                        if _private(a.name) and full.rsplit(".", 1)[0] != ".".join(package):
                            found.add((where, node.lineno, f"imports the private module {full}"))
                    elif _private(a.name):
                        found.add((where, node.lineno, f"imports {a.name} from {mod or top}"))
        for node in ast.walk(tree):
            if (read := _attribute_read(node)) is None or not _private(read[1]):
                continue
            obj, attr = read
            module = (_dotted(obj, aliases, top) or "").removeprefix(f"{top}.")
            if module in modules and module != name:
                found.add((where, node.lineno, f"uses {attr} of the module {module}"))
            elif attr in others and not _own(obj):
                found.add((where, node.lineno, f"uses {attr}, a private member of another module's class"))
    return [f"{where}:{line}: {what}" for where, line, what in sorted(found)]


def test_no_private_name_is_used_by_another_module():
    used = private_names_used_across_modules(SRC)
    assert not used, "private names used outside their module (make them public or move the use):\n" + "\n".join(used)


def test_a_private_name_used_by_another_module_is_found(tmp_path):
    pkg = tmp_path / "quadpilot"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("__version__ = '1'\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "_inner.py").write_text("X = 1\n")
    (pkg / "sub" / "a.py").write_text(
        "from . import _inner\n\ndef _hidden():\n    pass\n\n\nclass Policy:\n"
        "    def __init__(self):\n        self._state = 0\n\n    def _input(self, x):\n        return self._state\n"
    )
    (pkg / "b.py").write_text(
        "import quadpilot.sub.a\nimport quadpilot.sub.a as sa\nfrom quadpilot import __version__\n"
        "from quadpilot import sub\nfrom .sub.a import _hidden, Policy\nfrom .sub import _inner\n\n"
        "def run(policy):\n    sub.a._hidden()\n    quadpilot.sub.a._hidden()\n    sa._hidden()\n"
        "    getattr(policy, '_state')\n    sub.a.Policy().__init__()\n    return policy._input(1)\n\n\n"
        "class Mine(Policy):\n    def step(self):\n        return self._input(0) + super()._input(0)\n"
    )
    assert private_names_used_across_modules(pkg) == [
        "b.py:5: imports _hidden from sub.a",
        "b.py:6: imports the private module sub._inner",
        "b.py:9: uses _hidden of the module sub.a",
        "b.py:10: uses _hidden of the module sub.a",
        "b.py:11: uses _hidden of the module sub.a",
        "b.py:12: uses _state, a private member of another module's class",
        "b.py:14: uses _input, a private member of another module's class",
    ]


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
            if isinstance(node, ast.ImportFrom):
                if (mod := from_import_module(node, package, f"quadpilot.{train.name}")) is None:
                    continue  # another of our packages, or not ours
                names = [a.name for a in node.names]
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
