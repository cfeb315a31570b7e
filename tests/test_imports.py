"""Module boundaries: no module of the package reaches into another one's private names.

An underscore name is its module's own business (free to change without a caller noticing);
a name that another module needs is public. The scan is static (``ast``), so it is fast and
needs no JAX.
"""

from __future__ import annotations

import ast
from pathlib import Path

import transam

SRC = Path(transam.__file__).parent


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_module(name: str) -> bool:
    """Whether ``name`` (dotted) is a module or package of this source tree."""
    rel = Path(*name.split("."))
    return (SRC.parent / rel).with_suffix(".py").exists() or (SRC.parent / rel).is_dir()


def private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def absolute(node: ast.ImportFrom, here: str, is_package: bool) -> str:
    """The absolute module a (possibly relative) ``from ... import`` names."""
    if not node.level:
        return node.module or ""
    base = here.split(".") if is_package else here.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def violations(here: str, text: str, is_package: bool = False) -> list[str]:
    """Each use, in module ``here`` (source ``text``), of another module's private name."""
    tree = ast.parse(text, here)
    found = []
    modules: dict[str, str] = {}  # local name -> a transam module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "transam" and alias.asname:
                    modules[alias.asname] = alias.name
        elif isinstance(node, ast.ImportFrom):
            source = absolute(node, here, is_package)
            if source.split(".")[0] != "transam":
                continue
            for alias in node.names:
                if source != here and private(alias.name):
                    found.append(f"{here}: from {source} import {alias.name} (line {node.lineno})")
                elif is_module(f"{source}.{alias.name}"):
                    modules[alias.asname or alias.name] = f"{source}.{alias.name}"
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in modules
            and modules[node.value.id] != here
            and private(node.attr)
        ):
            target = modules[node.value.id]
            found.append(f"{here}: {target}.{node.attr} (line {node.lineno})")
    return found


def test_no_module_uses_another_modules_private_names() -> None:
    found = [
        v
        for path in sorted(SRC.rglob("*.py"))
        for v in violations(module_name(path), path.read_text(), path.name == "__init__.py")
    ]
    assert not found, "private names used across modules:\n" + "\n".join(found)


def test_the_scan_finds_private_names() -> None:
    """The checker itself: both forms are caught; a module's own names and dunders are not."""
    text = (
        "from transam.train.loop import _private, public\n"
        "from transam.train import config\n"
        "import transam.train.config as cfg\n"
        "from . import _sibling_private\n"
        "x = config._hidden + cfg._other + config.__name__ + public\n"
        "def _own():\n    return _own\n"
    )
    found = violations("transam.train.a2c", text)
    assert len(found) == 4, found
    for name in ("import _private", "config._hidden", "config._other", "_sibling_private"):
        assert any(name in f for f in found), name
