"""Every ```python block of README.md runs, in order, in one namespace (a later block may use
an earlier one's names), so the documented API cannot drift from the code.

Convention: a block fenced ```python skip-test is shown, not run (for a snippet that cannot
finish in seconds); prefer tiny settings that run. Names a block registers are removed after.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from transam import registry

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"^```python([^\n]*)\n(.*?)^```", re.MULTILINE | re.DOTALL)


def blocks() -> list[tuple[int, str, str]]:
    """(line, fence info after ``python``, code) of each python block."""
    text = README.read_text()
    return [
        (text[: m.start()].count("\n") + 1, m.group(1).strip(), m.group(2))
        for m in BLOCK.finditer(text)
    ]


def test_readme_has_python_blocks() -> None:
    assert len(blocks()) >= 2


def test_readme_python_blocks_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # anything a block writes by a relative path stays here
    envs, methods = registry.env_names(), registry.method_names()
    namespace: dict[str, object] = {"__name__": "readme"}
    try:
        for line, info, code in blocks():
            if info == "skip-test":
                continue
            assert info == "", f"README.md:{line}: unknown fence {info!r} (valid: skip-test)"
            exec(compile(code, f"README.md:{line}", "exec"), namespace)
    finally:
        for name in set(registry.env_names()) - set(envs):
            registry.unregister_env(name)
        for name in set(registry.method_names()) - set(methods):
            registry.unregister_method(name)
