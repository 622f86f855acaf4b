"""The layout's rules, read from the code: processing never sees the simulator or the world,
fusion takes plain measurements, everything lives under the `boomtip` namespace, and each
module keeps to one concern (a few hundred lines)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("data", "perception", "fusion", "tools")
MAX_MODULE_LINES = 420


def _sources(*roots: str) -> list[Path]:
    return sorted(p for r in roots for p in (ROOT / r).rglob("*.py"))


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            # `from boomtip.data import sim` imports the subpackage too
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


FORBIDDEN_FOR_PROCESSING = ("boomtip.data.sim", "boomtip.tools.config.scenario")


@pytest.mark.parametrize("root", ["perception", "fusion"])
def test_processing_never_imports_the_simulator_or_the_scenario(root):
    bad = [f"{p.relative_to(ROOT)}:{line} imports {m}"
           for p in _sources(root) for line, m in _imports(p)
           if any(m == f or m.startswith(f + ".") for f in FORBIDDEN_FOR_PROCESSING)]
    assert not bad, "\n".join(bad)


def test_fusion_never_imports_perception():
    bad = [f"{p.relative_to(ROOT)}:{line} imports {m}" for p in _sources("fusion")
           for line, m in _imports(p) if m == "boomtip.perception" or m.startswith("boomtip.perception.")]
    assert not bad, "\n".join(bad)


def test_no_bare_top_level_package_is_imported():
    bad = [f"{p.relative_to(ROOT)}:{line} imports {m}" for p in _sources(*PACKAGES, "tests")
           for line, m in _imports(p) if m.split(".")[0] in PACKAGES]
    assert not bad, "\n".join(bad)


def test_every_package_folder_is_installed():
    """pyproject's explicit package list must name every folder that holds modules."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {"boomtip." + ".".join(p.parent.relative_to(ROOT).parts) for p in _sources(*PACKAGES)}
    assert folders <= listed, f"not installed: {sorted(folders - listed)}"


def test_modules_keep_to_one_concern():
    big = [f"{p.relative_to(ROOT)} ({n} lines)" for p in _sources(*PACKAGES)
           for n in [len(p.read_text().splitlines())] if n > MAX_MODULE_LINES]
    assert not big, "split these: " + ", ".join(big)
