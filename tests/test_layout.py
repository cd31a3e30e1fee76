"""The house (issue 41): every name is imported from the module that defines it, no module
forwards names defined elsewhere, and no function is a 300-line pipeline or takes a dozen
parameters. Module size is not a rule; one job per module is."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "thrustmap"
DESIGN = ROOT / "docs" / "design.md"
MAX_FUNCTION_LINES = 120
MAX_PARAMETERS = 8

#: modules allowed to hold names defined elsewhere, and why
FORWARDING_ALLOWED = {
    # the public API: each name loaded from thrustmap.api on first use (docs/api.md)
    "thrustmap",
    # pyserial finds a URL handler as the module protocol_<scheme> and takes its Serial:
    # udpout is udpin's class under udpout's name
    "thrustmap.protocols.urlhandlers.protocol_udpout",
}

#: functions still over the limits until they are split (issue 41); the list only shrinks
TO_SPLIT_LONG: set[str] = set()
TO_SPLIT_PARAMETERS: set[str] = set()


# -- what each module defines, imports and reads -------------------------------------------------


@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    defines: set[str] = field(default_factory=set)
    #: module-level ``from x import n [as local]``: local -> (x, n)
    imports: dict[str, tuple[str, str]] = field(default_factory=dict)
    reads: set[str] = field(default_factory=set)
    exported: set[str] = field(default_factory=set)  # __all__


def _top_level(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    for st in body:
        yield st
        if isinstance(st, ast.If | ast.Try | ast.With | ast.For | ast.While):
            for block in ("body", "orelse", "finalbody"):
                yield from _top_level(getattr(st, block, []))
            for handler in getattr(st, "handlers", []):
                yield from _top_level(handler.body)


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def read_module(path: Path, root: Path = ROOT) -> Module:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    mod = Module(module_name(path, root), path, tree)
    for st in _top_level(tree.body):
        if isinstance(st, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            mod.defines.add(st.name)
        elif isinstance(st, ast.Assign | ast.AnnAssign | ast.AugAssign | ast.For):
            targets = st.targets if isinstance(st, ast.Assign) else [st.target]
            names = {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
            mod.defines |= names
            if "__all__" in names and isinstance(st.value, ast.List | ast.Tuple):
                mod.exported = {e.value for e in st.value.elts if isinstance(e, ast.Constant)}
        elif isinstance(st, ast.ImportFrom) and st.module and not st.level:
            for a in st.names:
                mod.imports[a.asname or a.name] = (st.module, a.name)
    mod.defines.discard("__all__")
    mod.reads = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    return mod


def product_modules(root: Path = ROOT) -> dict[str, Module]:
    return {
        m.name: m
        for m in (read_module(p, root) for p in sorted((root / "thrustmap").rglob("*.py")))
    }


def reexports(mod: Module) -> set[str]:
    """Names a module imports only to hand on: listed in its ``__all__`` or never read."""
    return {
        local
        for local, (source, _) in mod.imports.items()
        if source != "__future__" and (local in mod.exported or local not in mod.reads)
    }


def forwarding_modules(modules: dict[str, Module]) -> dict[str, set[str]]:
    return {
        name: names
        for name, mod in modules.items()
        if name not in FORWARDING_ALLOWED and (names := reexports(mod))
    }


def test_no_module_forwards_names_defined_elsewhere(tmp_path: Path) -> None:
    _the_checks_see_a_facade_and_its_users(tmp_path)
    forwarding = forwarding_modules(product_modules())
    assert not forwarding, "modules re-exporting names defined elsewhere (import from the " + (
        f"definer): {forwarding}"
    )


def _defined_in(modules: dict[str, Module], module: str, name: str) -> bool:
    mod = modules.get(module)
    if mod is None:
        return True  # not ours (a third-party module)
    if name in mod.defines or f"{module}.{name}" in modules:
        return True
    return module in FORWARDING_ALLOWED and name in mod.exported


def imports_through_forwarders(files: list[Path], modules: dict[str, Module]) -> list[str]:
    """Every ``from thrustmap.x import n`` and ``alias.n`` (on a module alias of ours) whose
    name the module does not define (it only imports it)."""
    found: list[str] = []
    for path in files:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases: dict[str, str] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                for a in node.names:
                    if f"{node.module}.{a.name}" in modules:
                        aliases[a.asname or a.name] = f"{node.module}.{a.name}"
                    elif a.name != "*" and not _defined_in(modules, node.module, a.name):
                        found.append(
                            f"{path.relative_to(ROOT)}:{node.lineno} {node.module}.{a.name}"
                        )
            elif isinstance(node, ast.Import):
                aliases |= {a.asname: a.name for a in node.names if a.asname in modules or a.asname}
        rebound = {n.arg for n in ast.walk(tree) if isinstance(n, ast.arg)} | {
            n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)
        }
        aliases = {k: v for k, v in aliases.items() if k not in rebound}  # a local of that name
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and aliases[node.value.id] in modules
                and not _defined_in(modules, aliases[node.value.id], node.attr)
                and not node.attr.startswith("__")
            ):
                found.append(
                    f"{path.relative_to(ROOT)}:{node.lineno} {aliases[node.value.id]}.{node.attr}"
                )
    return found


def _python_files() -> list[Path]:
    files: list[Path] = []
    for folder in ("thrustmap", "tests", "benchmarks", "scripts"):
        files += sorted((ROOT / folder).rglob("*.py"))
    return files


def test_nothing_is_imported_through_a_module_that_only_forwards_it() -> None:
    found = imports_through_forwarders(_python_files(), product_modules())
    assert len(found) == 0, "import these from the module that defines them:\n" + "\n".join(found)


def _the_checks_see_a_facade_and_its_users(tmp_path: Path) -> None:
    pkg = tmp_path / "thrustmap"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "real.py").write_text("def f() -> int:\n    return 1\n\nG = 2\n")
    (pkg / "facade.py").write_text('from thrustmap.real import G, f\n\n__all__ = ["G", "f"]\n')
    (pkg / "partial.py").write_text("from thrustmap.real import f\n\n\ndef h():\n    return f()\n")
    user = tmp_path / "user.py"
    user.write_text(
        "import thrustmap.facade as fa\nfrom thrustmap.partial import f, h\nfa.G\n"
        "from thrustmap.real import G\n"
    )
    modules = {m.name: m for m in (read_module(p, tmp_path) for p in sorted(pkg.glob("*.py")))}
    assert reexports(modules["thrustmap.facade"]) == {"G", "f"}
    assert reexports(modules["thrustmap.partial"]) == set()  # it reads f itself
    global ROOT
    old, ROOT = ROOT, tmp_path
    try:
        found = imports_through_forwarders([user], modules)
    finally:
        ROOT = old
    assert found == ["user.py:2 thrustmap.partial.f", "user.py:3 thrustmap.facade.G"]


# -- functions -------------------------------------------------------------------------------------


def _is_click_command(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    return any(
        re.search(r"\b(command|group)\b", ast.unparse(d.func if isinstance(d, ast.Call) else d))
        for d in fn.decorator_list
    )


def functions(
    modules: dict[str, Module],
) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    for name, mod in modules.items():
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                yield f"{name}:{node.name}", node


def parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    named = [*a.posonlyargs, *a.args, *a.kwonlyargs]
    return len([p for p in named if p.arg not in ("self", "cls")])


def _allowed_long() -> set[str]:
    """docs/design.md "Long functions": ``- `module.py: function`: reason``."""
    text = DESIGN.read_text(encoding="utf-8")
    m = re.search(r"^## Long functions\n(.*?)(?=^## )", text, re.M | re.S)
    assert m, "docs/design.md has no '## Long functions' section"
    allowed: set[str] = set()
    for path, fn, reason in re.findall(r"^- `([\w/]+)\.py: (\w+)`: (.+)$", m.group(1), re.M):
        assert len(reason.split()) >= 4, f"{path}: {fn}: give the reason"
        allowed.add(f"thrustmap.{path.replace('/', '.')}:{fn}")
    return allowed


def test_no_function_is_over_120_lines() -> None:
    allowed = _allowed_long()
    long = {
        key: fn.end_lineno - fn.lineno + 1  # type: ignore[operator]
        for key, fn in functions(product_modules())
        if fn.end_lineno - fn.lineno + 1 > MAX_FUNCTION_LINES  # type: ignore[operator]
    }
    new = {k: n for k, n in long.items() if k not in allowed | TO_SPLIT_LONG}
    assert not new, f"functions over {MAX_FUNCTION_LINES} lines (split them): {new}"
    done = TO_SPLIT_LONG - set(long)
    assert not done, f"now short: delete from TO_SPLIT_LONG: {sorted(done)}"


def test_no_function_takes_more_than_8_parameters() -> None:
    many = {
        key: parameters(fn)
        for key, fn in functions(product_modules())
        if parameters(fn) > MAX_PARAMETERS and fn.name != "__init__" and not _is_click_command(fn)
    }
    new = {k: n for k, n in many.items() if k not in TO_SPLIT_PARAMETERS}
    assert not new, f"functions over {MAX_PARAMETERS} parameters (use a config dataclass): {new}"
    done = TO_SPLIT_PARAMETERS - set(many)
    assert not done, f"now within the limit: delete from TO_SPLIT_PARAMETERS: {sorted(done)}"


@pytest.mark.parametrize("package", ["fitting.df", "flightlogs"])
def test_the_fleet_rules_key_covers_every_module_of_the_df_rules_and_the_readers(
    package: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Df rule or a reader edited in any module of ``fitting/df/`` or ``flightlogs/`` must
    change the fleet's options key (a re-run then re-extracts): the key hashes every one."""
    from thrustmap.fleet import run

    read: list[Path] = []
    original = Path.read_bytes

    def spy(self: Path) -> bytes:
        read.append(self.resolve())
        return original(self)

    monkeypatch.setattr(Path, "read_bytes", spy)
    run.rules_fingerprint()
    modules = {p.resolve() for p in (PACKAGE / package.replace(".", "/")).glob("*.py")}
    assert len(modules) > 1 and modules <= set(read)
