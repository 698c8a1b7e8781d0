"""The package's layout: imports flow one way (no cycles) and the library never imports its CLI.

The rule for cycles: **every** import statement counts, at module level or inside a function.
A function-level import that closes a circle only delays the failure to run time and still
means the two modules cannot be read, tested or changed apart. Imports under
``if TYPE_CHECKING:`` are exempt (they never run; they exist for annotations). A package's
``__init__`` depends on the submodules it imports; ``from . import x`` depends on submodule
``x`` when there is one, else on the package.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "pointviz"
#: The command-line layer, and the modules allowed to import it.
CLI_LAYER = ("pointviz.cli", "pointviz.commands")
CLI_USERS = ("pointviz.cli", "pointviz.commands", "pointviz.demo")


def _module_names(root: Path) -> dict[str, Path]:
    out = {}
    for f in sorted(root.rglob("*.py")):
        parts = f.relative_to(root.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST):
    """Every Import/ImportFrom node, skipping the bodies of ``if TYPE_CHECKING:``."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (see the module docstring for the rule)."""
    mods = _module_names(root)
    top = root.name

    def known(name: str) -> str | None:
        while name not in mods and "." in name:
            name = name.rsplit(".", 1)[0]
        return name if name in mods else None

    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        deps: set[str] = set()
        for node in _imports(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    prefix = ".".join(base + ([node.module] if node.module else []))
                else:
                    prefix = node.module or ""
                targets = [f"{prefix}.{a.name}" if f"{prefix}.{a.name}" in mods else prefix
                           for a in node.names]
            for t in targets:
                if t.split(".")[0] == top:
                    dep = known(t)
                    if dep is not None and dep != name:
                        deps.add(dep)
        graph[name] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def cli_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """(importer, CLI module) pairs where a library module imports the command-line layer."""
    def in_layer(m: str, layer: tuple[str, ...]) -> bool:
        return any(m == p or m.startswith(p + ".") for p in layer)

    return sorted((m, d) for m, deps in graph.items() for d in deps
                  if in_layer(d, CLI_LAYER) and not in_layer(m, CLI_USERS))


# -------------------------------------------------------------------------- the checker itself


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        f = root / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    return root / "pointviz"


def test_checker_finds_a_cycle_hidden_in_a_function(tmp_path):
    root = _write(tmp_path, {
        "pointviz/__init__.py": "",
        "pointviz/a.py": "from .b import f\n",
        "pointviz/b.py": "def f():\n    from . import a\n",
        "pointviz/c.py": "from . import a\n",
    })
    assert cycles(import_graph(root)) == [["pointviz.a", "pointviz.b"]]


def test_checker_resolves_relative_imports_in_subpackages(tmp_path):
    root = _write(tmp_path, {
        "pointviz/__init__.py": "",
        "pointviz/x.py": "import pointviz.sub.y\n",
        "pointviz/sub/__init__.py": "from .y import g\n",
        "pointviz/sub/y.py": "from .. import x\n",
        "pointviz/sub/z.py": "from ..x import thing\nfrom . import y\n",
    })
    g = import_graph(root)
    assert g["pointviz.sub"] == {"pointviz.sub.y"}
    assert g["pointviz.sub.z"] == {"pointviz.x", "pointviz.sub.y"}
    assert cycles(g) == [["pointviz.sub.y", "pointviz.x"]]


def test_checker_ignores_type_checking_imports(tmp_path):
    root = _write(tmp_path, {
        "pointviz/__init__.py": "",
        "pointviz/a.py": "from .b import f\n",
        "pointviz/b.py": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                          "    from .a import A\nelse:\n    import os\n"),
    })
    assert cycles(import_graph(root)) == []


def test_checker_finds_library_imports_of_the_cli(tmp_path):
    root = _write(tmp_path, {
        "pointviz/__init__.py": "",
        "pointviz/cli.py": "from .commands import common\n",
        "pointviz/commands/__init__.py": "",
        "pointviz/commands/common.py": "from ..lib import x\n",
        "pointviz/demo.py": "from .commands.common import y\n",
        "pointviz/lib.py": "def x():\n    from .commands.common import z\n",
    })
    assert cli_imports(import_graph(root)) == [("pointviz.lib", "pointviz.commands.common")]


# -------------------------------------------------------------------------- the package


@pytest.fixture(scope="module")
def graph():
    return import_graph(PACKAGE)


def test_the_package_has_no_import_cycles(graph):
    assert cycles(graph) == []


def test_only_the_cli_layer_imports_the_cli(graph):
    assert cli_imports(graph) == []
