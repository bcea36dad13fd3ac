"""Every package fastdet's code imports is declared in pyproject.toml, not only
pulled in by another package (which may drop it in any release)."""

import ast
import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def imported_top_level_names(folder):
    """Top-level names of every absolute import in the ``.py`` files under ``folder``."""
    names = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


def declared_distributions():
    """Normalised names of the distributions pyproject.toml asks for, its optional
    dependencies included, and those its requirements' extras ask for
    (``dask[distributed]`` asks for distributed, by dask's own metadata)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        requirements += extra
    declared = set()
    for requirement in requirements:
        name, extras = re.match(r"([A-Za-z0-9_.-]+)(?:\[([^\]]*)\])?", requirement).groups()
        declared.add(normalise(name))
        for extra in (extras or "").split(","):
            if extra.strip():
                declared |= extra_requirements(name, extra.strip())
    return declared


def extra_requirements(distribution, extra):
    """Normalised names of what ``distribution[extra]`` asks for, by its installed metadata."""
    marker = re.compile(r"extra\s*==\s*['\"]" + re.escape(extra) + r"['\"]")
    return {normalise(re.match(r"[A-Za-z0-9_.-]+", line).group(0))
            for line in importlib.metadata.requires(distribution) or []
            if marker.search(line)}


def normalise(name):
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_imported_package_is_declared():
    providers = importlib.metadata.packages_distributions()
    third_party = (imported_top_level_names(ROOT / "fastdet")
                   - set(sys.stdlib_module_names) - {"fastdet"})
    declared = declared_distributions()
    undeclared = {}
    for name in sorted(third_party):
        # Not installed: only a requirement whose marker leaves this Python out
        # (tomli before 3.11), declared under the name it is imported by.
        distributions = {normalise(d) for d in providers.get(name, [])} or {normalise(name)}
        if not distributions & declared:
            undeclared[name] = sorted(distributions)
    assert not undeclared, f"imported but not declared in pyproject.toml: {undeclared}"


def test_an_extra_declares_what_it_asks_for():
    assert "distributed" in extra_requirements("dask", "distributed")
    assert "distributed" not in extra_requirements("dask", "dataframe")


def test_the_scan_sees_imports_inside_functions(tmp_path):
    (tmp_path / "module.py").write_text("import os\n\ndef f():\n    import psutil.x\n"
                                        "    from numba.core import types\n"
                                        "    from . import sibling\n")
    assert imported_top_level_names(tmp_path) == {"os", "psutil", "numba"}
