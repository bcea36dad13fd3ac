"""The package's imports point one way: cli on top, kernels at the bottom, no circles.

Every ``import`` and ``from ... import`` of every module is read with ``ast``
(including imports inside functions, which run later but still tie the
modules together), resolved to the ``fastdet`` module it names, and checked
against the layers documented in ``docs/architecture.md``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "fastdet"

#: Layer of each top-level part of the package: a module may import its own
#: layer's parts below it in this list, never one above.  Parts on one line
#: (one layer) must not import each other, except where ALLOWED_SIDEWAYS says.
LAYERS = (
    ("cli",),
    ("batch",),
    ("training", "bench"),
    ("video",),
    ("evaluation", "viz"),
    ("detector",),
    ("files",),
    ("kernels", "errors"),
    ("compile_ahead",),
    ("_version",),
)
#: Imports between parts of one layer that the layout allows, as (from, to): none today.
ALLOWED_SIDEWAYS = frozenset()


def layer_of(part):
    for depth, parts in enumerate(LAYERS):
        if part in parts:
            return depth
    raise AssertionError(f"fastdet.{part} is not placed in a layer: add it to LAYERS and to "
                         "docs/architecture.md")


def module_name(path):
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imported_modules(path):
    """Every ``fastdet...`` module that ``path`` imports, with the line of the import."""
    name = module_name(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names
                      if alias.name.split(".")[0] == "fastdet"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "fastdet":
                continue
            # `from . import x` imports the submodule x when there is one.
            for alias in node.names:
                candidate = f"{target}.{alias.name}"
                found.append((candidate if is_module(candidate) else target, node.lineno))
    return found


def is_module(name):
    path = REPO / name.replace(".", "/")
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def package_modules():
    return sorted(PACKAGE.rglob("*.py"))


def part_of(module):
    """``"detector"`` for ``fastdet.detector.plan``, ``"errors"`` for ``fastdet.errors``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_every_part_has_a_layer():
    for child in PACKAGE.iterdir():
        if child.name.startswith(("_", ".")) or child.name == "data":
            continue
        if child.is_dir() or child.suffix == ".py":
            layer_of(child.stem)


def test_imports_point_down_or_sideways_within_a_layer():
    upward = []
    for path in package_modules():
        source = module_name(path)
        source_part = part_of(source)
        if source_part is None:  # fastdet/__init__.py: the public API may gather any layer
            continue
        for target, line in imported_modules(path):
            target_part = part_of(target)
            where = f"{path.relative_to(REPO)}:{line} imports {target}"
            if target_part is None:
                upward.append(f"{where} (the public API: import the module that defines it)")
            elif target_part == source_part:
                continue
            elif layer_of(target_part) < layer_of(source_part):
                upward.append(f"{where} (upward)")
            elif (layer_of(target_part) == layer_of(source_part)
                  and (source_part, target_part) not in ALLOWED_SIDEWAYS):
                upward.append(f"{where} (sideways within one layer)")
    assert upward == []


def test_no_module_imports_in_a_circle():
    graph = {module_name(p): {t for t, _ in imported_modules(p)} for p in package_modules()}
    # A package's __init__ runs before its modules; the facade re-exports, so
    # the edges into fastdet/__init__ are excluded above, and none remain.
    state, stack, circles = {}, [], []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in graph:
                continue
            if state.get(nxt) == "open":
                circles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert circles == []


@pytest.mark.parametrize("folder", ["benchmarks", "tools", "fastdet"])
def test_nothing_outside_cli_imports_cli(folder):
    offenders = []
    for path in sorted((REPO / folder).rglob("*.py")):
        if folder == "fastdet" and path.relative_to(PACKAGE).parts[0] == "cli":
            continue
        for target, line in imported_modules(path) if folder == "fastdet" else _any(path):
            if target == "fastdet.cli" or target.startswith("fastdet.cli."):
                offenders.append(f"{path.relative_to(REPO)}:{line} imports {target}")
    allowed = {"tools/build_default_model.py"}  # a script of fastdet commands, above the CLI
    assert [o for o in offenders if o.split(":")[0] not in allowed] == []


def _any(path):
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found += [(f"{node.module}.{a.name}", node.lineno) for a in node.names]
    return found


def test_the_checker_sees_a_circle_and_an_upward_import(tmp_path):
    """The rules above must be able to fail: a planted circle and upward import are found."""
    fake = tmp_path / "fastdet"
    (fake / "detector").mkdir(parents=True)
    (fake / "video").mkdir()
    for init in (fake / "__init__.py", fake / "detector" / "__init__.py",
                 fake / "video" / "__init__.py"):
        init.write_text("")
    (fake / "detector" / "a.py").write_text("from ..video import b\n")
    (fake / "video" / "b.py").write_text("from ..detector import a\n")
    globals()["REPO"], globals()["PACKAGE"] = tmp_path, fake
    try:
        with pytest.raises(AssertionError):
            test_imports_point_down_or_sideways_within_a_layer()
        with pytest.raises(AssertionError):
            test_no_module_imports_in_a_circle()
    finally:
        globals()["REPO"], globals()["PACKAGE"] = REPO_REAL, PACKAGE_REAL


REPO_REAL, PACKAGE_REAL = REPO, PACKAGE
