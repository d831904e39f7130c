"""The package layout of docs/ARCHITECTURE.md holds: every package is installed, imports go one
way (no cycles, lower layers never import higher ones) and long modules say why they are long.

The import graph is read from the source with ``ast`` (function-level imports included: a lazy
import still couples two modules), so the test needs nothing installed beyond the standard
library.
"""
from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: top-level packages and the folder each lives in (sc3d_cli is installed from cli/)
PACKAGE_DIRS = {"sc3d_data": "sc3d_data", "sc3d_train": "sc3d_train", "sc3d_cli": "cli"}
#: layers, lowest first: a module may import its own layer and lower ones only
LAYERS = [
    {"sc3d_data.geometry"},
    {"sc3d_data.io"},
    {"sc3d_data.formats", "sc3d_data.render", "sc3d_data.voxel"},
    {"sc3d_data.pipeline.run", "sc3d_data.qa"},
    {"sc3d_data.pipeline.executors"},
    {"sc3d_data.pipeline.jobs"},
    {"sc3d_train.settings"},
    {"sc3d_train.paper"},
    {"sc3d_train.data"},
    {"sc3d_train.loop"},
    {"sc3d_train.evaluation"},
    {"sc3d_cli"},
]
MAX_LINES = 300
LONG_MODULE_NOTE = re.compile(r"Length:")


def module_files() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the three packages."""
    out = {}
    for pkg, folder in PACKAGE_DIRS.items():
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO / folder).with_suffix("")
            parts = [pkg, *rel.parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def imported_modules(name: str, path: Path, known: set[str]) -> set[str]:
    """Modules of ``known`` that module ``name`` imports anywhere in its source (absolute and
    relative imports; ``from pkg import mod`` counts as importing ``pkg.mod``)."""
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                mod = ".".join(base[:len(base) - node.level + 1] + ([mod] if mod else []))
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        else:
            continue
        for t in targets:
            t = t.replace("cli.", "sc3d_cli.", 1) if t.startswith("cli.") else t
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def import_graph() -> dict[str, set[str]]:
    files = module_files()
    known = set(files)
    return {name: imported_modules(name, path, known) for name, path in files.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of module names (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for n in sorted(graph):
        if n not in state and (cycle := visit(n)):
            return cycle
    return None


def layer_of(module: str) -> int | None:
    for i, layer in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in layer):
            return i
    return None


# ----------------------------------------------------------------------------- checker controls
def test_cycle_finder_finds_a_hand_made_cycle_and_passes_a_dag():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_import_reader_sees_relative_and_lazy_imports(tmp_path):
    src = tmp_path / "mod.py"
    src.write_text("from . import sib\nfrom .other import thing\n\ndef f():\n    import p.deep\n")
    known = {"p", "p.mod", "p.sib", "p.other", "p.deep"}
    assert imported_modules("p.mod", src, known) == {"p", "p.sib", "p.other", "p.deep"}


# ----------------------------------------------------------------------------- the real tree
def test_every_package_folder_is_installed():
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    on_disk = {name for name, path in module_files().items() if path.name == "__init__.py"}
    assert on_disk == listed, f"pyproject.toml [tool.setuptools] packages differ: {on_disk ^ listed}"


def test_no_import_cycle():
    assert find_cycle(import_graph()) is None


#: package __init__ modules that group layers and sit in none (docstrings only)
GROUPING_PACKAGES = {"sc3d_data", "sc3d_train", "sc3d_data.pipeline"}


def test_every_module_sits_in_a_layer():
    """A module outside every layer would escape the check below (e.g. a new file dropped into
    sc3d_train/ beside the sub-packages instead of into one of them)."""
    loose = sorted(m for m in module_files() if layer_of(m) is None and m not in GROUPING_PACKAGES)
    assert not loose, "modules in no layer of LAYERS (put them in a sub-package): " + ", ".join(loose)


def test_imports_go_from_higher_layers_to_lower_ones():
    wrong = []
    for mod, deps in import_graph().items():
        lm = layer_of(mod)
        if lm is None:  # a top-level package __init__ (sc3d_data) sits below everything
            continue
        for d in deps:
            ld = layer_of(d)
            if ld is not None and ld > lm:
                wrong.append(f"{mod} imports {d}")
    assert not wrong, "imports against the layering of docs/ARCHITECTURE.md:\n" + "\n".join(sorted(wrong))


@pytest.mark.parametrize("name", sorted(module_files()))
def test_long_modules_say_why(name):
    path = module_files()[name]
    lines = path.read_text().count("\n")
    if lines <= MAX_LINES:
        return
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    assert LONG_MODULE_NOTE.search(doc), (f"{path.relative_to(REPO)} has {lines} lines (> {MAX_LINES}) and its "
                                          "docstring has no 'Length:' note saying why it is one module")
