"""The docs name what exists: ``docs/architecture.md``'s module index, the code names and paths in ``docs/``.

Read from the source with ``ast`` (nothing is imported), like ``tests/test_layering.py``:

- ``docs/architecture.md``'s module index has one row per module of ``src/semcityloc`` and no row for a
  module that does not exist, so a new module cannot go unmapped and a removed one cannot linger;
- every backticked dotted name in ``docs/*.md`` and ``README.md`` that starts with a module of the package
  (``geometry.pose.Pose``, ``refine.particle_filter``), one of its classes (``LocalizerConfig.x``) or a
  field typed with one (``refine.restarts``) names something the source defines. A setting that was tried
  and not kept is described in words, not written as if it were one;
- the docs point into the repository only: no scratch folder, the notes beside it marked as outside it.
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "semcityloc"
DOCS = ROOT / "docs"
ARCHITECTURE = DOCS / "architecture.md"
INDEX_HEADING = "## Module index"

# A dotted token ending in one of these is a file name (``run.json``, ``results.csv``), not code.
FILE_SUFFIXES = {
    "bin", "csv", "geojson", "gml", "gz", "html", "jpg", "jpeg", "json", "jsonl", "lock", "md", "mtl",
    "npy", "npz", "obj", "ply", "png", "pt", "py", "safetensors", "sh", "tif", "tiff", "toml", "txt",
    "xml", "yaml", "yml", "zip",
}  # fmt: skip
# Dotted names in the docs that are not this package's code, each with what it is.
NOT_CODE = {
    "crs.epsg": "a CityJSON 0.x metadata key",
    "config.return_class_token": "an attribute of transformers' DINOv3 config",
}
DOTTED = re.compile(r"(?:semcityloc\.)?[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)+")


def module_files() -> dict[str, Path]:
    """Module name relative to the package (``citymodel.model``; ``semcityloc`` for the root) -> its file."""
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts) or "semcityloc"] = path
    return out


def _class_members(node: ast.ClassDef) -> set[str]:
    """What ``Class.name`` may name: the body's definitions and assignments, and every ``self.x = ...``."""
    members = set()
    for item in node.body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            members.add(item.name)
        elif isinstance(item, (ast.Assign, ast.AnnAssign)):
            targets = item.targets if isinstance(item, ast.Assign) else [item.target]
            members |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
    for sub in ast.walk(node):
        if isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store):
            if isinstance(sub.value, ast.Name) and sub.value.id in ("self", "cls"):
                members.add(sub.attr)
    return members


def _annotation_names(annotation: ast.expr | None) -> set[str]:
    """The class names an annotation mentions (``X``, ``X | None``, ``"X"``, ``list[X]``)."""
    if annotation is None:
        return set()
    out = set()
    for node in ast.walk(annotation):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            out |= set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", node.value))
    return out


@cache
def source_index() -> dict[str, dict[str, set[str]]]:
    """What the source defines, read with ``ast``.

    ``names``: module -> its top-level names; ``members``: class -> its members (its bases' in the package
    too); ``basename``: a module's last name -> its full names (``refine`` -> ``localization.refine``);
    ``typed``: a field or argument name -> the classes it is annotated with (``refine`` -> ``RefineConfig``,
    ``model`` -> ``CityModel``), so that a config path (``refine.restarts``) or an attribute of a typed value
    (``model.pose_to_local``) can be checked.
    """
    names: dict[str, set[str]] = {}
    members: dict[str, set[str]] = {}
    bases: dict[str, set[str]] = {}
    basename: dict[str, set[str]] = {}
    typed: dict[str, set[str]] = {}
    for module, path in module_files().items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        found = set()
        for node in tree.body:
            for sub in [node, *(ast.walk(node) if isinstance(node, (ast.If, ast.Try)) else [])]:
                if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    found.add(sub.name)
                elif isinstance(sub, (ast.Assign, ast.AnnAssign)):
                    targets = sub.targets if isinstance(sub, ast.Assign) else [sub.target]
                    found |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
                elif isinstance(sub, (ast.Import, ast.ImportFrom)):
                    found |= {(a.asname or a.name).split(".")[0] for a in sub.names}
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                members.setdefault(node.name, set()).update(_class_members(node))
                bases.setdefault(node.name, set()).update(*(_annotation_names(b) for b in node.bases))
                for item in node.body:
                    if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                        typed.setdefault(item.target.id, set()).update(_annotation_names(item.annotation))
            elif isinstance(node, ast.arg):
                typed.setdefault(node.arg, set()).update(_annotation_names(node.annotation))
        names[module] = found
        basename.setdefault(module.split(".")[-1], set()).add(module)
    for cls in members:  # inherited members, from classes of the package
        todo, seen = list(bases[cls]), set()
        while todo:
            base = todo.pop()
            if base in members and base not in seen:
                seen.add(base)
                members[cls] |= members[base]
                todo.extend(bases[base])
    typed = {k: {c for c in v if c in members} for k, v in typed.items()}
    return {"names": names, "members": members, "basename": basename, "typed": typed}


def _in_module(module: str, rest: list[str]) -> bool:
    index = source_index()
    if not rest:
        return True
    if f"{module}.{rest[0]}" in module_files():  # a submodule
        return _in_module(f"{module}.{rest[0]}", rest[1:])
    if rest[0] not in index["names"].get(module, set()):
        return False
    return len(rest) == 1 or rest[0] not in index["members"] or _in_class(rest[0], rest[1:])


def _in_class(cls: str, rest: list[str]) -> bool:
    """``Class.member[.more]``: the member exists; a typed field is followed (``LocalizerConfig.refine.x``).

    What a member of no known type holds is not checked."""
    index = source_index()
    if rest[0] not in index["members"].get(cls, set()):
        return False
    if len(rest) == 1:
        return True
    classes = index["typed"].get(rest[0], set())
    return not classes or any(_in_class(c, rest[1:]) for c in classes)


def resolves(token: str) -> bool | None:
    """Whether a dotted code name exists in the source; None when it is not a name of the package.

    Tried in turn: a module path from the package (``localization.refine.particle_filter``: strict), a
    class (``LocalizerConfig.min_confidence_close_view``), a module by its last name
    (``refine.particle_filter``) or a field or argument typed with a class of the package
    (``refine.restarts``: ``LocalizerConfig.refine`` is a ``RefineConfig``); the name exists when any
    reading finds it.
    """
    parts = token.removeprefix("semcityloc.").split(".")
    if parts[-1] in FILE_SUFFIXES:
        return None
    index = source_index()
    if parts[0] in module_files():
        return _in_module(parts[0], parts[1:])
    readings = []
    if parts[0] in index["members"]:
        readings.append(_in_class(parts[0], parts[1:]))
    readings += [_in_module(m, parts[1:]) for m in index["basename"].get(parts[0], ())]
    readings += [_in_class(c, parts[1:]) for c in index["typed"].get(parts[0], ())]
    return any(readings) if readings else None


def code_names(text: str) -> list[tuple[int, str]]:
    """(line, token) for every dotted name inside backticks (a span may wrap a line; fenced blocks are
    shell, not names), not part of a path or a word (``benchmarks/x.py``, ``semcityloc-kernels.stamp``)."""
    text = re.sub(r"^```.*?^```", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.M | re.S)
    out = []
    for span in re.finditer(r"`([^`]+)`", text):
        inner = span.group(1)
        for match in DOTTED.finditer(inner):
            before = inner[match.start() - 1 : match.start()]
            after = inner[match.end() : match.end() + 1]
            if before in ("/", "-", ".") or after in ("/", "-"):
                continue
            out.append((text.count("\n", 0, span.start(1) + match.start()) + 1, match.group(0)))
    return out


def index_rows(text: str) -> list[str]:
    """The module named in the first cell of every table row of the module index."""
    start = text.index(INDEX_HEADING)
    end = text.find("\n## ", start + len(INDEX_HEADING))
    section = text[start : end if end != -1 else len(text)]
    return re.findall(r"^\| `([A-Za-z0-9_.]+)`", section, flags=re.M)


def test_every_module_is_in_the_architecture_module_index():
    rows = index_rows(ARCHITECTURE.read_text(encoding="utf-8"))
    modules = set(module_files())
    missing = sorted(modules - set(rows))
    assert not missing, f"modules with no row in {ARCHITECTURE.name}'s module index: {missing}"


def test_the_module_index_names_only_modules_that_exist_once():
    rows = index_rows(ARCHITECTURE.read_text(encoding="utf-8"))
    unknown = sorted(set(rows) - set(module_files()))
    assert not unknown, f"{ARCHITECTURE.name}'s module index names modules that do not exist: {unknown}"
    twice = sorted({r for r in rows if rows.count(r) > 1})
    assert not twice, f"modules with more than one row: {twice}"


@pytest.mark.parametrize("page", [*sorted(DOCS.glob("*.md")), ROOT / "README.md"], ids=lambda p: p.name)
def test_code_names_in_the_docs_exist(page: Path):
    names = code_names(page.read_text(encoding="utf-8"))
    bad = [
        f"{page.name}:{line}: `{tok}`"
        for line, tok in names
        if tok not in NOT_CODE and resolves(tok) is False
    ]
    assert not bad, "names in the docs that the source does not define:\n" + "\n".join(bad)


def test_the_name_check_tells_real_names_from_missing_ones():
    assert resolves("localization.search_reach.MapLayout.ground_below") is True
    assert resolves("refine.particle_filter") is True
    assert resolves("LocalizerConfig.min_confidence_close_view") is True
    assert resolves("citymodel.model.CityModel") is True
    assert resolves("localization.search_reach.MapLayout.nope") is False
    assert resolves("refine.fine_particles") is False
    assert resolves("LocalizerConfig.no_such_field") is False
    assert resolves("localization.no_such_module") is False
    assert resolves("run.json") is None
    assert resolves("np.float32") is None


REPO_PATH = re.compile(r"(?<![\w./-])((?:benchmarks|tests|src|docs)/[\w./-]+\.(?:py|md|json|toml))")


@pytest.mark.parametrize("page", [*sorted(DOCS.glob("*.md")), ROOT / "README.md"], ids=lambda p: p.name)
def test_the_docs_point_only_into_the_repository(page: Path):
    """No scratch folder (``/work/...``); the notes beside the repository said to be outside it; every
    ``benchmarks/``, ``tests/``, ``src/`` or ``docs/`` file named exists."""
    text = page.read_text(encoding="utf-8")
    bad = [
        f"{page.name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
        for m in re.finditer(r"/work/\S*", text)
    ]
    for m in re.finditer(r"\.\./shared/notes/\S*", text):
        if "beside the repository" not in text[m.end() : m.end() + 60].replace("\n", " "):
            bad.append(f"{page.name}: {m.group(0)} not marked as beside the repository, not in it")
    for m in REPO_PATH.finditer(text):
        if not (ROOT / m.group(1)).exists() and not (SRC / m.group(1)).exists():
            bad.append(f"{page.name}: {m.group(1)} is not in the repository")
    assert not bad, "paths that are not in the repository:\n" + "\n".join(bad)


def test_the_compile_notice_is_quoted_as_the_code_prints_it():
    """Stop 56 audit: docs/your-data.md quoted the notice of an older wording ("compiling numba kernels:
    about a minute, once per install (...)"). The quote is the line a command prints, word for word."""
    from semcityloc.benchmark.warmup import COMPILE_NOTICE
    from semcityloc.errors import as_flags

    text = " ".join((ROOT / "docs" / "your-data.md").read_text(encoding="utf-8").split())
    assert f"`semcityloc: {as_flags(COMPILE_NOTICE)}`" in text
