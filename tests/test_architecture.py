"""The package tree keeps the layers of docs/architecture.md: imports flow one way (a lower
layer never imports a higher one), stages never import each other, and no two modules
import each other in a circle, also through imports inside functions (lazy imports
count: they run, only later)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from conftest import REPO

PACKAGE = "vrsim_cli"

# Longest prefix wins. The table of docs/architecture.md, in code.
LAYERS = {
    "vrsim_cli": 0,  # the package itself: __version__ only
    "vrsim_cli.errors": 0,
    "vrsim_cli.text": 0,  # plurals and aligned tables for every command's output
    "vrsim_cli.maths": 0,
    "vrsim_cli.scene": 1,
    "vrsim_cli.model": 2,
    "vrsim_cli.kernels": 3,  # compiled loops of the stages: arrays in, arrays out
    "vrsim_cli.stages": 4,
    "vrsim_cli.render": 4,  # loop stage 3, handed to the loop as a callback
    "vrsim_cli.loop": 5,
    "vrsim_cli.writers": 6,
    "vrsim_cli.tools": 7,
    "vrsim_cli.cli": 8,
    "vrsim_cli.api": 8,  # the Python API, beside the CLI
    "vrsim_cli.__main__": 8,
}
# The one import allowed to go up: the package root re-exports the API lazily (PEP 562: an
# import inside its module-level `__getattr__`, run only when a user reads
# `vrsim_cli.load`), so `import vrsim_cli` stays cheap. It is left out of the graph; the
# tests below check that it is the only such import and that no module of the package
# reaches the API through the root.
LAZY_FACADE = {(PACKAGE, f"{PACKAGE}.api")}
STAGE_ROOTS = ("vrsim_cli.stages.", "vrsim_cli.render")


def modules(root: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the package under `root`."""
    found = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def lazy_imports(tree: ast.Module) -> set[int]:
    """ids of the import nodes inside a module-level `def __getattr__` (PEP 562)."""
    inside = set()
    for top in tree.body:
        if isinstance(top, ast.FunctionDef) and top.name == "__getattr__":
            inside |= {id(n) for n in ast.walk(top) if isinstance(n, (ast.Import, ast.ImportFrom))}
    return inside


def import_graph(root: Path, package: str = PACKAGE, lazy: list | None = None,
                 facade=frozenset(LAZY_FACADE)) -> dict[str, set[tuple[str, int]]]:
    """module -> {(imported module, line)} for imports of the package's own modules,
    wherever they stand in the file. `from a.b import c` is an edge to a.b.c when that is a
    module, else to a.b. Edges in `facade` made from the package root's `__getattr__` are
    left out and appended to `lazy` as (module, target, line)."""
    known = modules(root, package)
    graph: dict[str, set[tuple[str, int]]] = {name: set() for name in known}
    for name, path in known.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(), str(path))
        in_getattr = lazy_imports(tree) if name == package else set()
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: resolve against this module's package
                    here = name.split(".") if is_package else name.split(".")[:-1]
                    here = here[:len(here) - node.level + 1]
                    base = ".".join(here + ([base] if base else []))
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.append(sub if sub in known else base)
            for target in targets:
                if target == package or target.startswith(package + "."):
                    while target not in known and "." in target:  # a name in a module
                        target = target.rsplit(".", 1)[0]
                    if target == name:
                        continue
                    if id(node) in in_getattr and (name, target) in facade:
                        if lazy is not None:
                            lazy.append((name, target, node.lineno))
                        continue
                    graph[name].add((target, node.lineno))
    return graph


def cycles(graph: dict[str, set[tuple[str, int]]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w, _ in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def layer_of(module: str, layers: dict[str, int] = LAYERS) -> int:
    best = max((p for p in layers if module == p or module.startswith(p + ".")), key=len,
               default=None)
    if best is None:
        raise AssertionError(f"{module} is in no layer of docs/architecture.md")
    return layers[best]


def stage_of(module: str) -> str | None:
    """The stage a module belongs to (vrsim_cli.stages.X or vrsim_cli.render), or None."""
    for root in STAGE_ROOTS:
        if module == root or module.startswith(root if root.endswith(".") else root + "."):
            if root.endswith("."):
                return root + module[len(root):].split(".")[0]
            return root
    return None


def violations(graph, layers: dict[str, int] = LAYERS) -> list[str]:
    """Upward imports and imports from one stage into another, as readable lines."""
    bad = []
    for module, edges in sorted(graph.items()):
        for target, line in sorted(edges):
            if layer_of(target, layers) > layer_of(module, layers):
                bad.append(f"{module}:{line} imports {target} (layer "
                           f"{layer_of(target, layers)} above {layer_of(module, layers)})")
            a, b = stage_of(module), stage_of(target)
            if a and b and a != b:
                bad.append(f"{module}:{line} imports {target}: stages never import each other")
    return bad


def test_the_package_has_no_import_cycle():
    assert cycles(import_graph(REPO)) == []


def test_imports_flow_down_the_layers_and_stages_stay_apart():
    assert violations(import_graph(REPO)) == []


def test_the_lazy_api_import_is_the_only_way_up_and_nothing_uses_it():
    """The root's `__getattr__` imports vrsim_cli.api and nothing else; no module of the
    package reads an API name from the root (that would close a cycle through the API)."""
    lazy: list = []
    import_graph(REPO, lazy=lazy)
    assert [(m, t) for m, t, _ in lazy] == [(PACKAGE, f"{PACKAGE}.api")]
    api_names = set(__import__(PACKAGE).API)
    for module, path in modules(REPO).items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module == PACKAGE and not node.level:
                taken = {alias.name for alias in node.names} & api_names
                assert not taken, f"{module} imports {taken} from the package root"


def test_the_facade_exemption_is_narrow(tmp_path):
    """Only an import inside the root's `__getattr__` is exempt: the same import at
    module level, or of another module, is still an upward import."""
    root = _fake_package(tmp_path, {
        "api.py": "x = 1\n",
        "cli.py": "y = 1\n",
    })
    (root / PACKAGE / "__init__.py").write_text(
        "def __getattr__(name):\n    from vrsim_cli import api\n    from vrsim_cli import cli\n"
        "from vrsim_cli import api\n")
    bad = violations(import_graph(root))
    assert bad == ["vrsim_cli:4 imports vrsim_cli.api (layer 8 above 0)",
                   "vrsim_cli:3 imports vrsim_cli.cli (layer 8 above 0)"]


def test_every_module_is_in_a_layer():
    for module in modules(REPO):
        layer_of(module)


def _fake_package(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / PACKAGE / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in [p for p in (tmp_path / PACKAGE).rglob("*") if p.is_dir()] + \
            [tmp_path / PACKAGE]:
        (folder / "__init__.py").touch()
    return tmp_path


def test_a_lazy_cycle_is_found(tmp_path):
    """The checker itself: a cycle closed by an import inside a function is reported."""
    root = _fake_package(tmp_path, {
        "tools/a.py": "from vrsim_cli.tools.b import x\n",
        "tools/b.py": "def x():\n    from vrsim_cli.tools import a\n",
        "tools/c.py": "import vrsim_cli.tools.a\n",
    })
    assert cycles(import_graph(root)) == [["vrsim_cli.tools.a", "vrsim_cli.tools.b"]]


def test_an_upward_import_and_a_stage_importing_a_stage_are_found(tmp_path):
    root = _fake_package(tmp_path, {
        "model/model.py": "def f():\n    from vrsim_cli.stages.collision.shapes import g\n",
        "stages/collision/shapes.py": "g = 1\n",
        "stages/navigation.py": "from vrsim_cli.stages.collision import shapes\n",
        "loop.py": "from vrsim_cli.stages import navigation\n",
    })
    assert violations(import_graph(root)) == [
        "vrsim_cli.model.model:2 imports vrsim_cli.stages.collision.shapes (layer 4 above 2)",
        "vrsim_cli.stages.navigation:1 imports vrsim_cli.stages.collision.shapes: stages "
        "never import each other",
    ]


# ----------------------------------------------------------------------------- docs

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_doc_link_and_code_path_resolves(doc):
    """Relative links resolve to files; `path/to/file.py`-like names in code spans name
    files that exist (from the repository or the package root), so a moved module cannot
    leave a stale path behind."""
    text = doc.read_text()
    missing = []
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if "://" in target or target.startswith("mailto:"):
            continue
        if not (doc.parent / target).exists():
            missing.append(f"link {target}")
    basenames = {p.name for folder in (PACKAGE, "tests", "benchmarks", "scenarios")
                 for p in (REPO / folder).rglob("*") if p.is_file()}
    for span in re.findall(r"`([^`\s]+)`", text):
        path = span.split("::")[0].split(":")[0]
        if not re.fullmatch(r"[\w./-]*[\w-]\.(py|json|yaml|obj|toml)", path):
            continue
        if "/" not in path:  # a bare file name must still be a file of ours
            if path not in basenames and not (REPO / path).exists():
                missing.append(f"file {path}")
            continue
        top = path.split("/")[0]
        if not path.endswith(".py") and not any((base / top).exists() for base in
                                                (REPO, REPO / PACKAGE, doc.parent)):
            continue  # an output folder of a command (bench/bench.json)
        candidates = [REPO / path, REPO / PACKAGE / path, doc.parent / path]
        if not any(c.exists() for c in candidates):
            missing.append(f"path {path}")
    if missing:
        pytest.fail(f"{doc.name}: stale {missing}")
