"""Imports run only downstream: a package may import only packages before it in FLOW, never after.

FLOW is the one place the order is written; the README's "Package layout" section quotes it and a
test below keeps the two equal. Every import is read, including those inside functions.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ushape"

# Building blocks (file I/O, run-folder names, checkpoints, building configured objects), then the
# data's way: procedural shapes, datasets and rendering, grids and marching cubes, the scoring maths,
# stage 1, stage 2, fusion, propagation, recalibration, refinement on the views, reconstruction,
# next-best-view planning, and the commands built on all of them, with the `ushape` command that runs each of them last.
FLOW = (
    "torchvision_cpu",
    "atomic",
    "workspace",
    "checkpoints",
    "builders",
    "shapes",
    "data",
    "mesh",
    "metrics",
    "decoder",
    "encoder",
    "fusion",
    "propagation",
    "recalibration",
    "refinement",
    "reconstruction",
    "planning",
    "training",
    "evaluation",
    "bench",
    "cli",
)
FLOW_LINE = " -> ".join(FLOW)


def unit_of(path: Path) -> str:
    """The top-level unit of ushape a file belongs to: its subpackage, or its module's name."""
    first = path.relative_to(PACKAGE).parts[0]
    return first.removesuffix(".py")


def imported_units(path: Path) -> set[tuple[str, int]]:
    """(unit of ushape imported, line) for every absolute `ushape.` import in the file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        names = []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] if node.module != "ushape" else [f"ushape.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        found |= {(name.split(".")[1], node.lineno) for name in names if name.startswith("ushape.")}
    return found


def test_every_unit_of_the_package_has_a_place_in_the_flow():
    units = {unit_of(p) for p in PACKAGE.rglob("*.py")} - {"__init__"}
    assert units <= set(FLOW), f"add these to FLOW (and the README's layout section): {sorted(units - set(FLOW))}"


def test_imports_run_only_downstream():
    rank = {unit: i for i, unit in enumerate(FLOW)}
    against = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = unit_of(path)
        if source == "__init__":  # ushape/__init__.py runs torchvision_cpu, the first unit
            continue
        for target, line in sorted(imported_units(path)):
            if target != source and rank.get(target, len(FLOW)) > rank[source]:
                against.append(f"{path.relative_to(ROOT)}:{line} ({source} imports {target})")
    assert not against, "imports against the flow " + FLOW_LINE + ":\n" + "\n".join(against)


def test_the_readme_states_the_same_flow():
    assert FLOW_LINE in (ROOT / "README.md").read_text(encoding="utf-8"), (
        f"the README's layout section must quote the flow as written in this test: {FLOW_LINE}"
    )


@pytest.mark.parametrize("source, target", [("decoder", "encoder"), ("mesh", "decoder")])
def test_the_check_catches_an_upstream_import(tmp_path, source, target):
    """A file of `source` that imports `target` (later in FLOW) is what the check reports."""
    offending = tmp_path / "m.py"
    offending.write_text(f"def f():\n    from ushape.{target}.x import y\n")
    assert imported_units(offending) == {(target, 2)}
    assert FLOW.index(target) > FLOW.index(source)
