"""The house's layout: no import loop between modules (imports inside functions count), and the
app's domains point one way (the manual's Development, "Layout and layering")."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from tests.helpers import REPO

PACKAGES = ("app", "weldpool_core")
BELOW_REVIEW = ("frames", "training", "proposals")
"""App domains that ``app.review`` sits above: they never import it."""
LAYERS = (
    ("__main__", "cli", "main", "demo", "manual"),
    ("imports",),
    ("review", "timeline", "metrics", "process", "web"),
    ("teacher", "training", "live"),
    ("frames", "labelconfig"),
    ("proposals",),
    ("jobs", "users", "system", "storage", "core"),
)
"""The app's packages from the top down (docs/development.md): each imports only from its own
layer and those below."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _under_type_checking(node: ast.AST, parents: dict[int, ast.AST]) -> bool:
    while id(node) in parents:
        node = parents[id(node)]
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return True
    return False


def import_graph() -> dict[str, set[str]]:
    """Every module of ``app`` and ``weldpool_core`` → the modules of both it imports at run
    time, wherever the import stands (not under ``if TYPE_CHECKING``)."""
    files = {_module_name(p): p for package in PACKAGES for p in (REPO / package).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text())
        parents = {
            id(child): node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)
        }
        found: set[str] = set()
        for node in ast.walk(tree):
            if _under_type_checking(node, parents):
                continue
            if isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module)
                found |= {f"{node.module}.{alias.name}" for alias in node.names}
        graph[name] = {m for m in found if m in files and m != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in sorted(graph[node]):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def _is_package_import(graph: dict[str, set[str]], module: str, target: str) -> bool:
    return target in graph and module == target.rsplit(".", 1)[0]


def test_no_import_loop_between_modules() -> None:
    graph = import_graph()
    # a package's __init__ naming its own modules is not a loop through them
    for name, targets in graph.items():
        graph[name] = {t for t in targets if not _is_package_import(graph, name, t)}
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_loop() -> None:
    """The check above fails on a loop (a finder that finds nothing would pass anything)."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


JS_IMPORT = re.compile(
    r"""^\s*(?:import|export)\b[^;]*?\bfrom\s*["'](\.\.?/[^"']+)["']|^\s*import\s*["'](\.\.?/[^"']+)["']""",
    re.MULTILINE,
)
"""A static ``import … from "./x.js"`` (or ``"../x.js"``, ``export … from``, a bare ``import``)."""


def js_import_graph(root: Path = REPO / "static" / "js") -> dict[str, set[str]]:
    """Every browser module under ``static/js`` → the modules it imports statically, as paths
    relative to ``root``."""
    graph: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.js")):
        found = set()
        for match in JS_IMPORT.finditer(path.read_text(encoding="utf-8")):
            target = (path.parent / (match.group(1) or match.group(2))).resolve()
            found.add(target.relative_to(root.resolve()).as_posix())
        graph[path.relative_to(root).as_posix()] = found
    return {name: {t for t in targets if t in graph} for name, targets in graph.items()}


def test_no_import_loop_between_browser_modules() -> None:
    """A page's modules by concern subscribe to its state's changes; none imports back the
    module that renders or starts the page."""
    assert _cycles(js_import_graph()) == []


def test_the_browser_import_graph_sees_a_planted_loop(tmp_path: Path) -> None:
    """The JS graph finds imports across folders and lines, so the check above can fail."""
    (tmp_path / "page").mkdir()
    (tmp_path / "api.js").write_text('export const api = 1;\nimport "./page/view.js";\n')
    (tmp_path / "page" / "view.js").write_text(
        'import {\n  a,\n  b,\n} from "./panel.js";\nconst x = import("../lone.js");\n'
    )
    (tmp_path / "page" / "panel.js").write_text('export { c } from "../api.js";\n')
    (tmp_path / "page" / "lone.js").write_text('import { api } from "../api.js";\n')
    graph = js_import_graph(tmp_path)
    assert graph["page/view.js"] == {"page/panel.js"}  # a dynamic import() is no static edge
    assert _cycles(graph) == [["api.js", "page/panel.js", "page/view.js"]]
    (tmp_path / "api.js").write_text("export const api = 1;\n")
    assert _cycles(js_import_graph(tmp_path)) == []


def test_domains_below_review_never_import_it() -> None:
    graph = import_graph()
    wrong = sorted(
        f"{module} → {target}"
        for module, targets in graph.items()
        for target in targets
        if module.split(".")[:2] in [["app", d] for d in BELOW_REVIEW]
        and target.startswith("app.review")
    )
    assert wrong == []


def test_the_core_library_never_imports_the_service() -> None:
    graph = import_graph()
    wrong = sorted(
        f"{m} → {t}"
        for m, ts in graph.items()
        if m.startswith("weldpool_core")
        for t in ts
        if t.startswith("app")
    )
    assert wrong == []


def test_app_packages_import_only_downwards() -> None:
    layer = {package: i for i, names in enumerate(LAYERS) for package in names}
    packages = {p.name for p in (REPO / "app").iterdir() if p.is_dir() and p.name != "__pycache__"}
    packages |= {p.stem for p in (REPO / "app").glob("*.py") if p.stem != "__init__"}
    assert packages <= set(layer), sorted(packages - set(layer))  # a new package needs a layer
    upwards = sorted(
        f"{module} → {target}"
        for module, targets in import_graph().items()
        for target in targets
        if module.startswith("app.")
        and target.startswith("app.")
        and layer[target.split(".")[1]] < layer[module.split(".")[1]]
    )
    assert upwards == []


MAX_FUNCTION_LINES = 80


def test_no_function_over_80_lines() -> None:
    """Long functions are split by job (one epoch, validate, save), not into halves."""
    long = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                    if lines > MAX_FUNCTION_LINES:
                        long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({lines})")
    assert long == []


LONG_MODULES = {
    "weldpool_core/student/train.py": 643,
    "app/training/tasks.py": 611,
}
"""Modules over ``MAX_MODULE_LINES`` and the lines each may have at most: they may only shrink
(split one by job and lower or drop its entry here)."""
MAX_MODULE_LINES = 600


def test_modules_over_600_lines_may_only_shrink() -> None:
    """No new module grows past 600 lines, and the few that are longer never grow."""
    grown = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            name = path.relative_to(REPO).as_posix()
            lines = len(path.read_text().splitlines())
            if lines > LONG_MODULES.get(name, MAX_MODULE_LINES):
                grown.append(f"{name} ({lines} lines)")
    assert grown == []


def cross_test_imports(root: Path = REPO / "tests") -> list[str]:
    """``file → name`` for every import, inside functions too, of a ``test_*`` module (or of a
    name in one) by any module under ``root``: shared builders live in ``tests/factories.py``,
    browser helpers in ``tests/pages.py``, fixtures in a ``conftest.py``."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                module = node.module or ""
                names = [module, *(f"{module}.{alias.name}" for alias in node.names)]
                ours = node.level > 0 or module.split(".")[0] == root.name
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
                ours = True
            else:
                continue
            for name in names:
                parts = name.split(".")
                if (
                    ours
                    and parts[0] in (root.name, "")
                    and any(p.startswith("test_") for p in parts)
                ):
                    found.append(f"{path.relative_to(root.parent).as_posix()} → {name}")
                    break
    return found


def test_no_test_module_imports_another() -> None:
    """A test module imports helpers from the shared modules, never from another test module
    (whose tests would then run twice, and whose private helpers become everyone's)."""
    assert cross_test_imports() == []


def test_the_cross_test_finder_sees_a_planted_import(tmp_path: Path) -> None:
    """The check above can fail: an import of a test module, even inside a function or
    relative, is found; one of a shared module is not."""
    tests = tmp_path / "tests"
    (tests / "a").mkdir(parents=True)
    (tests / "factories.py").write_text("def upload() -> None: ...\n")
    (tests / "a" / "test_one.py").write_text("from tests.factories import upload\n")
    (tests / "a" / "test_two.py").write_text(
        "def test_x() -> None:\n    from tests.a.test_one import upload\n"
    )
    (tests / "a" / "test_three.py").write_text("from . import test_one\nimport tests.a.test_two\n")
    assert cross_test_imports(tests) == [
        "tests/a/test_three.py → .test_one",
        "tests/a/test_three.py → tests.a.test_two",
        "tests/a/test_two.py → tests.a.test_one",
    ]
