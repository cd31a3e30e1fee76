"""What imports what (docs/design.md "Arrows" and "What imports what"): no import cycle between
files, and every arrow between the package's folders is one the design page's table allows."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DESIGN = ROOT / "docs" / "design.md"


# -- what imports what ----------------------------------------------------------------------------

#: import cycles between files that remain, each the sorted modules of one strongly connected
#: component of the import graph; docs/design.md lists the same. The list only shrinks: a cycle
#: not listed fails, and so does a listed one that is gone (delete its line).
KNOWN_CYCLES: set[tuple[str, ...]] = set()


def import_graph(root: Path, package: str = "thrustmap") -> dict[str, set[str]]:
    """module -> the package's modules it imports, wherever the import is (module level, inside
    a function, under ``TYPE_CHECKING``): ``import a.b``, ``from a import b`` (the submodule
    ``a.b`` when there is one, else ``a``), relative imports, and ``importlib.import_module``
    of a constant, a module-level constant or an f-string of them (an f-string whose tail is
    computed: every module under its constant head). A file that imports a name it computes
    otherwise imports every module named by a string it holds. A package's ``__init__`` run
    because a child was imported is Python's doing, not an import of the child's file."""
    import ast

    modules: dict[str, Path] = {}
    for path in (root / package).rglob("*.py"):
        name = ".".join(path.relative_to(root).with_suffix("").parts)
        modules[name.removesuffix(".__init__")] = path
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        here = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        constants: dict[str, str] = {}
        for stmt in tree.body:
            value = getattr(stmt, "value", None)
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                targets = (
                    stmt.targets
                    if isinstance(stmt, ast.Assign)
                    else [getattr(stmt, "target", None)]
                )
                constants |= {t.id: value.value for t in targets if isinstance(t, ast.Name)}

        def text(node: ast.AST, constants: dict[str, str] = constants) -> str | None:
            if isinstance(node, ast.Constant):
                return node.value if isinstance(node.value, str) else None
            if isinstance(node, ast.Name):
                return constants.get(node.id)
            if isinstance(node, ast.FormattedValue):
                return text(node.value)
            if isinstance(node, ast.JoinedStr):
                parts = [text(v) for v in node.values]
                return "".join(p for p in parts if p is not None) if None not in parts else None
            return None

        found: set[str] = set()
        strings: set[str] = set()
        computed = False
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = (
                    here.split(".")[: len(here.split(".")) - node.level + 1] if node.level else []
                )
                module = ".".join(base + ([node.module] if node.module else []))
                for alias in node.names:
                    sub = f"{module}.{alias.name}"
                    found.add(sub if sub in modules else module)
            elif isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names}
            elif (
                isinstance(node, ast.Call)
                and node.args
                and "import_module"
                in (getattr(node.func, "attr", None), getattr(node.func, "id", None))
            ):
                arg = node.args[0]
                target = text(arg)
                head = (
                    text(arg.values[0]) if isinstance(arg, ast.JoinedStr) and arg.values else None
                )
                if target is not None:
                    found.add(target)
                elif head:
                    found |= {m for m in modules if m.startswith(head)}
                else:
                    computed = True
            elif isinstance(node, (ast.Constant, ast.JoinedStr)):
                value = text(node)
                if value is not None:
                    strings.add(value)
        if computed:
            found |= strings
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> set[tuple[str, ...]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: set[tuple[str, ...]] = set()
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            child = next(edges, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.add(tuple(sorted(component)))
    return cycles


def test_no_import_cycle_between_files() -> None:
    cycles = import_cycles(import_graph(ROOT))
    assert cycles <= KNOWN_CYCLES, sorted(cycles - KNOWN_CYCLES)
    assert cycles >= KNOWN_CYCLES, (
        f"broken, delete from KNOWN_CYCLES: {sorted(KNOWN_CYCLES - cycles)}"
    )
    everything = {m for cycle in cycles for m in cycle}
    assert "thrustmap.fitting.export.encodings" not in everything


def test_the_cycle_check_sees_every_kind_of_import(tmp_path: Path) -> None:
    """A ring of four files closed by a lazy, a relative, a ``from pkg import submodule`` and an
    ``importlib.import_module`` import is one cycle; without the last link there is none."""
    pkg = tmp_path / "thrustmap"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    import thrustmap.sub.b\n")
    (pkg / "sub" / "b.py").write_text("from . import c\n")
    (pkg / "sub" / "c.py").write_text("from thrustmap import d\n")
    (pkg / "d.py").write_text(
        'import importlib\nNAME = "thrustmap.a"\nimportlib.import_module(NAME)\n'
    )
    (pkg / "e.py").write_text('import importlib\nimportlib.import_module(f"thrustmap.{x}")\n')
    graph = import_graph(tmp_path)
    assert graph["thrustmap.a"] == {"thrustmap.sub.b"}
    assert graph["thrustmap.sub.b"] == {"thrustmap.sub.c"}
    assert graph["thrustmap.sub.c"] == {"thrustmap.d"}
    assert graph["thrustmap.d"] == {"thrustmap.a"}
    assert "thrustmap.a" in graph["thrustmap.e"]
    ring = ("thrustmap.a", "thrustmap.d", "thrustmap.sub.b", "thrustmap.sub.c")
    assert import_cycles(graph) == {ring}
    (pkg / "d.py").write_text('import importlib\nNAME = "thrustmap.a"\n')
    assert import_cycles(import_graph(tmp_path)) == set()


# -- the arrows between folders ------------------------------------------------------------------


def folder_of(module: str) -> str:
    """The design page's name for a module's place: a folder of the package (``rig``), a
    top-level module (``demo.py``), or the package itself (``__init__.py``)."""
    parts = module.split(".")
    if len(parts) == 1:
        return "__init__.py"
    if len(parts) == 2 and not (ROOT / "thrustmap" / parts[1]).is_dir():
        return f"{parts[1]}.py"
    return parts[1]


def allowed_arrows(design: str) -> dict[str, set[str]]:
    """docs/design.md's "What imports what" table: folder -> what it may import (a folder, a
    top-level module, or one module as ``folder/file.py``); ``cli`` may import everything."""
    m = re.search(r"^## What imports what\n(.*?)(?=^## )", design, re.M | re.S)
    assert m, "docs/design.md has no '## What imports what' section"
    table: dict[str, set[str]] = {}
    for row in re.findall(r"^\| `([^`]+)` \| (.*) \|$", m.group(1), re.M):
        source, targets = row
        table[source] = set(re.findall(r"`([^`]+)`", targets))
        if targets.startswith("everything"):
            table[source] = {"*"}
    assert {"core", "protocols", "flightlogs", "rig", "fitting", "cli"} <= set(table), table
    return table


def arrows_against_the_design(root: Path, design: str) -> list[str]:
    """Every import between folders that the table does not allow, as 'a -> b (module -> module)'."""
    table = allowed_arrows(design)
    wrong: list[str] = []
    for module, imported in sorted(import_graph(root).items()):
        source = folder_of(module)
        allowed = table.get(source)
        if allowed is None:
            wrong.append(f"{source}: not in the design page's table ({module})")
            continue
        for target in sorted(imported):
            dest = folder_of(target)
            as_file = target.removeprefix("thrustmap.").replace(".", "/") + ".py"
            if dest == source or "*" in allowed or dest in allowed or as_file in allowed:
                continue
            wrong.append(f"{source} -> {dest} ({module} -> {target})")
    return wrong


def test_every_arrow_between_folders_is_in_the_design_page() -> None:
    wrong = arrows_against_the_design(ROOT, DESIGN.read_text(encoding="utf-8"))
    assert not wrong, "imports docs/design.md does not allow:\n" + "\n".join(wrong)


def test_the_arrow_check_fails_on_an_arrow_the_table_lacks(tmp_path: Path) -> None:
    """The layer rule "rig imports only core and protocols" broke unseen (issue 41): the check
    finds such an arrow, and one allowed by a single module's line."""
    pkg = tmp_path / "thrustmap"
    for folder in ("core", "protocols", "flightlogs", "rig", "fitting", "cli"):
        (pkg / folder).mkdir(parents=True)
        (pkg / folder / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "units.py").write_text("")
    (pkg / "flightlogs" / "series.py").write_text("from thrustmap.core import units\n")
    (pkg / "rig" / "stream.py").write_text(
        "def f():\n    from thrustmap.flightlogs import series\n"
    )
    (pkg / "demo.py").write_text("from thrustmap.cli import textwidth\n")
    (pkg / "cli" / "textwidth.py").write_text("from thrustmap.rig import stream\n")
    design = (
        "## What imports what\n\n| folder | imports |\n|---|---|\n"
        "| `core` | nothing of thrustmap |\n| `protocols` | `core` |\n"
        "| `flightlogs` | `core` |\n| `rig` | `core`, `protocols` |\n| `fitting` | `core` |\n"
        "| `demo.py` | `core`, `cli/textwidth.py` (its table layout) |\n"
        "| `__init__.py` | `core` |\n| `cli` | everything above |\n\n## Next\n"
    )
    assert arrows_against_the_design(tmp_path, design) == [
        "rig -> flightlogs (thrustmap.rig.stream -> thrustmap.flightlogs.series)"
    ]
    allowed = design.replace(
        "| `rig` | `core`, `protocols` |", "| `rig` | `core`, `protocols`, `flightlogs` |"
    )
    assert arrows_against_the_design(tmp_path, allowed) == []
