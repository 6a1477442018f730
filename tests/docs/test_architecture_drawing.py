"""docs/architecture.md's drawing of the packages is the code's (docs/architecture_drawing.py)."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("architecture_drawing", ROOT / "docs" / "architecture_drawing.py")
drawing = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(drawing)


def test_the_drawing_in_architecture_md_is_made_from_the_code():
    assert drawing.main(["--check"]) == 0, "run: python docs/architecture_drawing.py"


def test_a_new_import_changes_the_drawing(tmp_path):
    src = tmp_path / "quadpilot"
    for pkg, body in (("core", ""), ("link", "from quadpilot.core import x\n"), ("runtime", "from ..link import y\n")):
        (src / pkg).mkdir(parents=True)
        (src / pkg / "m.py").write_text(body)
    graph = drawing.package_graph(src)
    assert graph == {"core": set(), "link": {"core"}, "runtime": {"link"}}
    text = drawing.drawing(graph)
    assert "    link --> core\n" in text and "    runtime --> link\n" in text and "    core\n" in text
    doc = f"a\n{drawing.BEGIN}\nold\n{drawing.END}\nb"
    assert drawing.with_drawing(doc, graph) == f"a\n{drawing.BEGIN}\n{text}\n{drawing.END}\nb"
