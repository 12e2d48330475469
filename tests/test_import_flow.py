"""Imports run only downstream: a package may import only packages before it in FLOW, never after;
and inside a package folder, no two of its modules import each other, directly or in a loop.

FLOW is the one place the order is written; the README's "Package layout" section quotes it and a
test below keeps the two equal. Every import is read, including those inside functions.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ushape"

# Building blocks (the bad-input error type, file I/O, run-folder names, checkpoints, building configured
# objects), then the data's way: procedural shapes, datasets and rendering, grids and marching cubes, the
# scoring maths, stage 1, stage 2, fusion, propagation, recalibration, refinement on the views,
# reconstruction, next-best-view planning, and the commands built on all of them, with the `ushape`
# command that runs each of them last.
FLOW = (
    "torchvision_cpu",
    "errors",
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


def test_the_docs_state_the_same_flow():
    """docs/package_layout.md quotes the flow in full; the README's layout section links to it."""
    layout = ROOT / "docs" / "package_layout.md"
    assert FLOW_LINE in layout.read_text(encoding="utf-8"), (
        f"{layout.relative_to(ROOT)} must quote the flow as written in this test: {FLOW_LINE}"
    )
    assert "docs/package_layout.md" in (ROOT / "README.md").read_text(encoding="utf-8"), (
        "the README's layout section must link docs/package_layout.md"
    )


@pytest.mark.parametrize("source, target", [("decoder", "encoder"), ("mesh", "decoder")])
def test_the_check_catches_an_upstream_import(tmp_path, source, target):
    """A file of `source` that imports `target` (later in FLOW) is what the check reports."""
    offending = tmp_path / "m.py"
    offending.write_text(f"def f():\n    from ushape.{target}.x import y\n")
    assert imported_units(offending) == {(target, 2)}
    assert FLOW.index(target) > FLOW.index(source)


def folder_units(folder: Path) -> dict[str, list[Path]]:
    """The units of one package folder: each module, and each subpackage (all of its files), by name."""
    units = {p.stem: [p] for p in folder.glob("*.py") if p.stem != "__init__"}
    units |= {d.name: sorted(d.rglob("*.py")) for d in folder.iterdir() if (d / "__init__.py").is_file()}
    return units


def sibling_imports(folder: Path, root: Path = ROOT) -> dict[str, set[str]]:
    """unit -> the other units of the same folder it imports (absolute or relative, inside functions too)."""
    dotted = ".".join(folder.relative_to(root).parts)
    units = folder_units(folder)
    edges = {unit: set() for unit in units}
    for unit, paths in units.items():
        for path in paths:
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
                edges[unit] |= set(_siblings(node, dotted, path.parent.relative_to(root).parts)) & set(units) - {unit}
    return edges


def _siblings(node: ast.AST, dotted: str, package: tuple[str, ...]) -> list[str]:
    """The names right under `dotted` that an import node of a file in `package` reaches."""
    if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
    elif isinstance(node, ast.ImportFrom) and node.level:
        base = ".".join(package[: len(package) - node.level + 1])
        module = f"{base}.{node.module}" if node.module else base
        names = [module] if node.module else [f"{module}.{a.name}" for a in node.names]
    elif isinstance(node, ast.ImportFrom) and node.module:
        names = [node.module] if node.module != dotted else [f"{dotted}.{a.name}" for a in node.names]
    else:
        return []
    return [name[len(dotted) + 1 :].split(".")[0] for name in names if name.startswith(dotted + ".")]


def import_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected sets of more than one unit (Tarjan): each is a loop of imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(unit: str) -> None:
        index[unit] = low[unit] = len(index)
        stack.append(unit)
        for other in sorted(edges[unit]):
            if other not in index:
                visit(other)
                low[unit] = min(low[unit], low[other])
            elif other in stack:
                low[unit] = min(low[unit], index[other])
        if low[unit] == index[unit]:
            loop = []
            while not loop or loop[-1] != unit:
                loop.append(stack.pop())
            if len(loop) > 1:
                found.append(sorted(loop))

    for unit in sorted(edges):
        if unit not in index:
            visit(unit)
    return found


def test_no_two_modules_of_a_package_import_each_other():
    folders = sorted({p.parent for p in PACKAGE.rglob("__init__.py")})
    loops = [
        f"{folder.relative_to(ROOT)}: {' <-> '.join(loop)}"
        for folder in folders
        for loop in import_cycles(sibling_imports(folder))
    ]
    assert not loops, "modules that import each other (move what both need into a third module):\n" + "\n".join(loops)


def test_the_cycle_check_catches_a_loop_through_a_function_level_import(tmp_path):
    """a -> b -> c -> a, the last one inside a function, is one loop; d importing a is not part of it."""
    folder = tmp_path / "ushape" / "pkg"
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "a.py").write_text("from ushape.pkg import b\n")
    (folder / "b.py").write_text("from .c import f\n")
    (folder / "c.py").write_text("def f():\n    import ushape.pkg.a\n")
    (folder / "d.py").write_text("from ushape.pkg.a import x\n")
    edges = sibling_imports(folder, tmp_path)
    assert edges == {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycles(edges) == [["a", "b", "c"]]
