"""The package's import structure: layers only point down, no import cycles, imports at module top.

The layers (``docs/architecture.md``, whose table ``ALLOWED`` must equal: parsed below), each allowed to
import only what is listed for it:

    cli -> benchmark -> baselines -> (localization, perception, datasets) -> render -> citymodel
        -> (geometry, evaluation) -> io -> classes -> errors (cache: nothing of the package)

Read from the source with ``ast`` (nothing is imported), so a violation anywhere in ``src/`` fails here:
imports inside functions, imports under ``if TYPE_CHECKING:`` (they must point down too), and modules
named as strings for ``importlib.import_module`` (a literal argument, or any string constant naming a
semcityloc module in a file that calls it with a variable: ``benchmark.warmup.KERNEL_GROUPS``). An import
that is not at module top needs a comment on its line or just above it giving the reason: the heavy or
optional dependency it defers (``REASON_WORDS``), or "lazy", "optional", "cycle", "type checkers".
Each check is also run on a deliberately bad snippet, to show it can fail.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "semcityloc"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
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
# What a comment on an import inside a function (or under TYPE_CHECKING) must name: the heavy optional
# dependencies of docs/architecture.md, or why else the import waits.
REASON_WORDS = re.compile(
    r"\b(torch|transformers|matplotlib|plotly|ray|pycolmap|embreex?|nvdiffrast|moge|safetensors|"
    r"weights package|optional|lazy|cycle|type checkers)\b",
    re.IGNORECASE,
)


class Import(NamedTuple):
    name: str  # the semcityloc module (or module.attribute) imported
    line: int
    at_top: bool  # a plain import statement in the module's body (what runs on import: the cycle graph)
    kind: str  # "import", "type_checking" or "string"


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


def _calls_import_module(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
    return name in ("import_module", "__import__")


def imports(source: str, module: str, is_package: bool, known: dict[str, Path]) -> list[Import]:
    """Every semcityloc import of ``source`` (the text of ``module``): statements anywhere, those under
    ``if TYPE_CHECKING:`` marked as such, and string imports (module docstring)."""
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    type_checking = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            type_checking |= {id(n) for n in ast.walk(node)}
    out = []
    dynamic = False  # import_module called with something other than a string literal
    for node in ast.walk(tree):
        if _calls_import_module(node):
            arg = node.args[0] if node.args else None
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                if arg.value.split(".")[0] == "semcityloc":
                    out.append(Import(arg.value, node.lineno, False, "string"))
            else:
                dynamic = True
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
        kind = "type_checking" if id(node) in type_checking else "import"
        for name in names:
            if name == "semcityloc" or name.startswith("semcityloc."):
                out.append(Import(name, node.lineno, id(node) in top, kind))
    if dynamic:  # the module names it may import are the string constants naming one
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in known:
                out.append(Import(node.value, node.lineno, False, "string"))
    return out


def resolve(name: str, known: dict[str, Path]) -> str | None:
    """The module ``name`` refers to (``pkg.mod.attr`` -> ``pkg.mod``)."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def upward_imports(source: str, module: str, known: dict[str, Path], is_package: bool = False) -> list[str]:
    """``line: pkg imports other (target, kind)`` for each import of ``source`` the layering forbids."""
    pkg = package_of(module)
    assert pkg in ALLOWED, f"{module}: package {pkg!r} is missing from the layering table"
    wrong = []
    for imp in imports(source, module, is_package, known):
        target = resolve(imp.name, known)
        if target is None:
            continue
        other = package_of(target)
        if other != pkg and other not in ALLOWED[pkg]:
            wrong.append(f"{imp.line}: {pkg} imports {other} ({target}, {imp.kind})")
    return sorted(set(wrong))


def test_imports_only_point_down_the_layers():
    known = modules()
    wrong = []
    for module, path in known.items():
        problems = upward_imports(path.read_text(encoding="utf-8"), module, known, path.name == "__init__.py")
        wrong += [f"{path.relative_to(SRC.parent)}:{p}" for p in problems]
    assert wrong == [], "\n".join(sorted(set(wrong)))


def test_no_import_cycles_between_modules():
    known = modules()
    graph = {m: set() for m in known}
    for module, path in known.items():
        for imp in imports(path.read_text(encoding="utf-8"), module, path.name == "__init__.py", known):
            target = resolve(imp.name, known)
            if imp.at_top and target is not None and target != module:
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


def _reason_comment(lines: list[str], node: ast.stmt) -> str:
    """The comments of an import statement: on its own lines, and the comment lines just above it (across
    a run of imports: one comment may explain two adjacent imports)."""
    end = getattr(node, "end_lineno", None) or node.lineno
    text = [line.split("#", 1)[1] for line in lines[node.lineno - 1 : end] if "#" in line]
    k = node.lineno - 2
    while k >= 0:
        above = lines[k].strip()
        if above.startswith("#"):
            text.append(above[1:])
        elif not above.startswith(("import ", "from ")):
            break
        k -= 1
    return " ".join(text)


def silent_local_imports(source: str) -> list[str]:
    """``line: statement`` of each import not at module top whose comment gives no reason."""
    lines = source.splitlines()
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    silent = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top:
            if isinstance(node, ast.ImportFrom) and node.module == "__future__":
                continue
            if not REASON_WORDS.search(_reason_comment(lines, node)):
                silent.append(f"{node.lineno}: {lines[node.lineno - 1].strip()}")
    return silent


def test_imports_inside_functions_say_why():
    silent = []
    for path in sorted(SRC.rglob("*.py")):
        problems = silent_local_imports(path.read_text(encoding="utf-8"))
        silent += [f"{path.relative_to(SRC.parent)}:{p}" for p in problems]
    assert silent == [], "\n".join(silent)


# ------------------------------------------------------------------------------ the table in the docs
def layer_table(markdown: str) -> dict[str, set[str]]:
    """The "| package | may import |" table of ``markdown`` as {package: packages it may import}.

    A cell reads: "nothing ..." (none); "everything" or "everything but `x`" (every package of the table
    but the row's own, ``__main__`` and ``x``); otherwise the backticked packages, and with "and below"
    each of them together with everything it may import in turn.
    """
    rows = []
    in_table = False
    for line in markdown.splitlines():
        if re.match(r"\|\s*package\s*\|\s*may import\s*\|", line):
            in_table = True
            continue
        if in_table and line.startswith("|---"):
            continue
        if in_table and not line.startswith("|"):
            break
        if in_table:
            left, right = (cell.strip() for cell in line.strip().strip("|").split("|"))
            rows.append((re.findall(r"`(\w+)`", left), right))
    if not rows:
        raise AssertionError("no '| package | may import |' table found")
    everything = {p for names, _ in rows for p in names}
    cells = {p: right for names, right in rows for p in names}
    table: dict[str, set[str]] = {}
    visiting: set[str] = set()  # a table that drifted upward may loop: "and below" stops there

    def allowed(pkg: str) -> set[str]:
        if pkg not in table:
            cell = cells[pkg]
            named = set(re.findall(r"`(\w+)`", cell))
            if cell.startswith("nothing"):
                return table.setdefault(pkg, set())
            if cell.startswith("everything"):
                own = next(names for names, _ in rows if pkg in names)
                return table.setdefault(pkg, everything - set(own) - {"__main__"} - named)
            if "and below" not in cell or pkg in visiting:
                return named if pkg in visiting else table.setdefault(pkg, named)
            visiting.add(pkg)
            table[pkg] = set().union(*({n} | allowed(n) for n in named))
            visiting.discard(pkg)
        return table[pkg]

    for pkg in cells:
        allowed(pkg)
    return table


def drift(documented: dict[str, set[str]]) -> dict[str, tuple[list[str], list[str]]]:
    """{package: (what the docs allow, what ALLOWED allows)} where the two differ."""
    return {
        pkg: (sorted(documented.get(pkg, {"(absent)"})), sorted(ALLOWED.get(pkg, {"(absent)"})))
        for pkg in documented.keys() | ALLOWED.keys()
        if documented.get(pkg) != ALLOWED.get(pkg)
    }


def test_the_layering_table_is_the_one_in_architecture_md():
    differ = drift(layer_table(ARCHITECTURE.read_text(encoding="utf-8")))
    assert differ == {}, f"docs/architecture.md vs ALLOWED: {differ}"


@pytest.mark.parametrize(
    "pkg, forbidden", [("geometry", "citymodel"), ("render", "localization"), ("datasets", "benchmark")]
)
def test_the_documented_table_forbids_upward_imports(pkg, forbidden):
    assert forbidden not in layer_table(ARCHITECTURE.read_text(encoding="utf-8"))[pkg]


# ------------------------------------------------------------------------ each check on a bad example
def test_an_upward_import_under_type_checking_is_caught():
    source = (
        "from typing import TYPE_CHECKING\n\n"
        "if TYPE_CHECKING:\n"
        "    # for type checkers only\n"
        "    from semcityloc.benchmark.spec import BenchmarkSpec\n"
    )
    wrong = upward_imports(source, "semcityloc.geometry.bad", modules())
    assert wrong == ["5: geometry imports benchmark (semcityloc.benchmark.spec, type_checking)"]
    assert silent_local_imports(source) == []  # its comment gives the reason


def test_an_upward_string_import_is_caught():
    literal = "import importlib\n\ndef f():\n    return importlib.import_module('semcityloc.cli.main')\n"
    assert upward_imports(literal, "semcityloc.render.bad", modules()) == [
        "4: render imports cli (semcityloc.cli.main, string)"
    ]
    # Named in a table and imported through a variable (like benchmark.warmup.KERNEL_GROUPS).
    table = (
        "from importlib import import_module\n\n"
        "KERNELS = ('semcityloc.render.raster_numba', 'semcityloc.localization.kernels')\n\n"
        "def load():\n    return [import_module(name) for name in KERNELS]\n"
    )
    assert upward_imports(table, "semcityloc.render.bad", modules()) == [
        "3: render imports localization (semcityloc.localization.kernels, string)"
    ]
    assert upward_imports(table, "semcityloc.benchmark.fine", modules()) == []


def test_an_import_inside_a_function_without_a_reason_is_caught():
    bad = "def f():\n    # see below\n    import numpy\n\n\ndef g():\n    import scipy  # noqa: F401\n"
    assert silent_local_imports(bad) == ["3: import numpy", "7: import scipy  # noqa: F401"]
    good = (
        "def f():\n    import torch  # torch: a heavy dependency\n\n\n"
        "def g():\n    # optional [reference] extra, probed only\n    import embreex.a  # noqa: F401\n"
        "    import embreex.b  # noqa: F401\n\n\n"
        "def h():\n    from semcityloc.cli.main import main  # lazy: over a second to import\n"
    )
    assert silent_local_imports(good) == []


def test_a_table_in_the_docs_that_drifted_is_caught():
    text = ARCHITECTURE.read_text(encoding="utf-8")
    row = "| `geometry` | `io`, `classes`, `errors` |"
    assert row in text
    drifted = layer_table(text.replace(row, "| `geometry` | `citymodel`, `io`, `classes`, `errors` |"))
    assert "geometry" in drift(drifted) and "citymodel" in drift(drifted)["geometry"][0]
    # "and below" follows the rows it names: render's table grows with what citymodel may import.
    grown = layer_table(
        text.replace(
            "| `citymodel` | `cache`, `__init__`, `geometry` and below |",
            "| `citymodel` | `cache`, `__init__`, `geometry` and below, `perception` |",
        )
    )
    assert "perception" in grown["render"] and {"citymodel", "render"} <= set(drift(grown))
    no_row = layer_table(text.replace("| `__main__` (`python -m semcityloc`) | `cli` |\n", ""))
    assert drift(no_row) == {"__main__": (["(absent)"], ["cli"])}
