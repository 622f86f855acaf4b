"""The layout's rules, read from the code: data/ sits below everything, processing never sees
the simulator or the world, fusion takes plain measurements, no module reaches into another's
private names, no import loops, everything lives under the `boomtip` namespace, each module
keeps to one concern (a few hundred lines), and a chain is thin wiring."""

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


@pytest.mark.parametrize("root", ["data"])
def test_data_imports_nothing_above_it(root):
    above = ("boomtip.perception", "boomtip.fusion", "boomtip.tools")
    bad = [f"{p.relative_to(ROOT)}:{line} imports {m}" for p in _sources(root) for line, m in _imports(p)
           if any(m == a or m.startswith(a + ".") for a in above)]
    assert not bad, "\n".join(bad)


def test_processing_never_imports_the_tools():
    bad = [f"{p.relative_to(ROOT)}:{line} imports {m}" for p in _sources("perception", "fusion")
           for line, m in _imports(p) if m == "boomtip.tools" or m.startswith("boomtip.tools.")]
    assert not bad, "\n".join(bad)


def test_no_module_imports_another_modules_private_names():
    bad = []
    for p in _sources(*PACKAGES):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("boomtip."):
                bad += [f"{p.relative_to(ROOT)}:{node.lineno} imports {node.module}.{a.name}"
                        for a in node.names if a.name.startswith("_")]
    assert not bad, "\n".join(bad)


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return "boomtip." + ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_import_loops_between_modules():
    """Module-level imports only (an import inside a function runs when it is called)."""
    graph: dict[str, set[str]] = {}
    names = {_module_name(p) for p in _sources(*PACKAGES)}
    for p in _sources(*PACKAGES):
        deps = set()
        for node in ast.parse(p.read_text()).body:
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module] + [f"{node.module}.{a.name}" for a in node.names] if isinstance(node, ast.ImportFrom) and node.module else [])
            deps |= {m for m in mods if m in names}
        graph[_module_name(p)] = deps - {_module_name(p)}
    state: dict[str, int] = {}
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in graph.get(m, ()):
            if state.get(d) == 1:
                cycles.append(" -> ".join(path[path.index(d):] + [d]) if d in path else f"{m} -> {d}")
            elif d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, "\n".join(cycles)


# a chain's per-frame code: everything but these (construction, finishing, outputs, kpis,
# report and visualisation, and methods named finish_* or visualis*); a chain that holds more
# decides what its pipeline or estimator should
NOT_PER_FRAME = {"__init__", "frames", "finish", "outputs", "kpis", "report", "picture", "frame_score", "close",
                 "visualiser", "visualise_result"}  # frame_score: which frame the picture shows
MAX_PER_FRAME_LINES = 60


def test_a_chain_is_thin_wiring():
    fat = []
    for p in _sources("tools/chains"):
        for node in ast.parse(p.read_text()).body:
            if isinstance(node, ast.ClassDef) and node.name.endswith("Chain"):
                methods = [f for f in node.body if isinstance(f, ast.FunctionDef) and f.name not in NOT_PER_FRAME
                           and not f.name.lstrip("_").startswith(("finish", "visualis"))]
                lines = sum(f.end_lineno - f.lineno + 1 for f in methods)
                if lines > MAX_PER_FRAME_LINES:
                    fat.append(f"{p.relative_to(ROOT)}:{node.name} {lines} lines ({', '.join(f.name for f in methods)})")
    assert not fat, "\n".join(fat)


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
