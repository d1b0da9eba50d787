"""The package's import structure: layers only point down, no import cycles, imports at module top.

The layers (``docs/architecture.md``), each allowed to import only what is listed for it:

    cli -> benchmark -> baselines -> (localization, perception, datasets) -> render -> citymodel
        -> (geometry, evaluation) -> io -> classes -> errors (cache: nothing of the package)

Read from the source with ``ast`` (nothing is imported), so a violation anywhere in ``src/`` fails here,
including imports inside functions. An import inside a function is allowed only with a comment on its line
or the line above saying why (a heavy optional dependency: torch, matplotlib, pycolmap, embree, ray...).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "semcityloc"
FOUNDATION = {"cache", "classes", "errors", "io", "__init__"}
_BELOW_RENDER = {"citymodel", "geometry", "evaluation", *FOUNDATION}
_PIPELINE = {"render", *_BELOW_RENDER}
ALLOWED: dict[str, set[str]] = {
    "__init__": {"classes", "errors"},
    "cache": set(),
    "classes": {"errors"},
    "errors": set(),
    "io": {"classes", "errors"},
    "geometry": {"classes", "errors", "io"},
    "evaluation": {"geometry", "classes", "errors"},
    "citymodel": {"geometry", *FOUNDATION},
    "render": _BELOW_RENDER,
    "localization": _PIPELINE,
    "perception": _PIPELINE,
    "datasets": _PIPELINE,
    "baselines": {"localization", *_PIPELINE},
    "benchmark": {"baselines", "localization", "perception", "datasets", *_PIPELINE},
    "cli": {"benchmark", "baselines", "localization", "perception", "datasets", *_PIPELINE},
    "__main__": {"cli"},  # python -m semcityloc: the command
}


def modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        parts = path.relative_to(SRC.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def package_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports(path: Path, module: str) -> list[tuple[str, int, bool]]:
    """(imported semcityloc module, line, at module level) for every import in the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(node) for node in tree.body}
    type_checking = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            type_checking |= {id(n) for n in ast.walk(node)}
    is_package = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if id(node) in type_checking:
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import: resolve against this module
                base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            names = [target] + [f"{target}.{a.name}" for a in node.names]
        else:
            continue
        for name in names:
            if name == "semcityloc" or name.startswith("semcityloc."):
                out.append((name, node.lineno, id(node) in top))
    return out


def resolve(name: str, known: dict[str, Path]) -> str | None:
    """The module ``name`` refers to (``pkg.mod.attr`` -> ``pkg.mod``)."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def test_imports_only_point_down_the_layers():
    known = modules()
    wrong = []
    for module, path in known.items():
        pkg = package_of(module)
        assert pkg in ALLOWED, f"{module}: package {pkg!r} is missing from the layering table"
        for name, line, _ in imports(path, module):
            target = resolve(name, known)
            if target is None:
                continue
            other = package_of(target)
            if other != pkg and other not in ALLOWED[pkg]:
                wrong.append(f"{path.relative_to(SRC.parent)}:{line}: {pkg} imports {other} ({target})")
    assert wrong == [], "\n".join(sorted(set(wrong)))


def test_no_import_cycles_between_modules():
    known = modules()
    graph = {m: set() for m in known}
    for module, path in known.items():
        for name, _, at_top in imports(path, module):
            target = resolve(name, known)
            if at_top and target is not None and target != module:
                graph[module].add(target)
    cycles = strongly_connected(graph)
    # A package __init__ re-exporting its own modules is fine: a module importing the package it is in
    # through the __init__ is not (that is the cycle).
    assert cycles == [], "\n".join(" -> ".join(sorted(c)) for c in cycles)


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's algorithm: the components with more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[set[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_imports_inside_functions_say_why():
    silent = []
    for path in sorted(SRC.rglob("*.py")):
        lines = path.read_text(encoding="utf-8").splitlines()
        tree = ast.parse("\n".join(lines))
        top = {id(node) for node in tree.body}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top:
                if isinstance(node, ast.ImportFrom) and node.module == "__future__":
                    continue
                here, above = lines[node.lineno - 1], lines[node.lineno - 2] if node.lineno > 1 else ""
                if "#" not in here and not above.strip().startswith("#"):
                    silent.append(f"{path.relative_to(SRC.parent)}:{node.lineno}: {here.strip()}")
    assert silent == [], "\n".join(silent)


@pytest.mark.parametrize(
    "pkg, forbidden", [("geometry", "citymodel"), ("render", "localization"), ("datasets", "benchmark")]
)
def test_the_layering_table_forbids_upward_imports(pkg, forbidden):
    assert forbidden not in ALLOWED[pkg]
