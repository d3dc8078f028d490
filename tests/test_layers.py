"""The package's layers, checked from the source: every import goes down, no part reaches into another's privates.

The parts of ``iiwa_ident``, bottom first (docs/layout.md, "Layout"). A part may import
the parts of lower layers, never of its own layer or above, so nothing below
the CLI imports the CLI and there are no import cycles between parts; the packages of
:data:`PUBLIC_API` are imported only through their ``__init__``.
Imports inside functions count. The root package's own helper modules
(``errors``, ``_toml``, ``_schema``, ``_json``, ``_realtime``, ``_blas``, ``_defaults``, ``_h5tree``) are the
foundation every part may use; beyond those, no part imports a private
module (``_name``) or a private name of another part. Between modules there is no import circle,
not even through imports made only for the type checker.

The harness of the tests and the benchmarks (``iiwa_ident.testing``) stands above every layer: no part
imports it. It and ``bench/`` use the library as a user does, through the packages' public APIs.
"""

from __future__ import annotations

import ast
from pathlib import Path

import iiwa_ident

LAYERS: tuple[tuple[str, ...], ...] = (
    ("iiwa_ident", "errors", "_toml", "_schema", "_json", "_realtime", "_blas", "_defaults", "_h5tree"),
    ("model", "references", "robot"),
    ("description",),
    ("fri", "netft"),
    ("datasets",),
    ("sim",),
    ("excite",),
    ("ident",),
    ("design",),
    ("deploy", "diagnose"),
    ("runtime", "emulator"),
    ("pipeline", "fleet"),
    ("report",),
    ("cli",),
    ("testing",),  # the harness: outside the library, which never imports it
)
FOUNDATION = set(LAYERS[0])
ROOT = Path(iiwa_ident.__file__).parent


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "iiwa_ident"


def _file_imports(path: Path):
    """(line, imported module, imported names) of every iiwa_ident import in one file."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("iiwa_ident"):
            yield node.lineno, node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("iiwa_ident"):
                    yield node.lineno, a.name, []


def _imports():
    """(file, line, importing part, imported module, imported names) of every iiwa_ident import."""
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        own = _part(".".join(p for p in rel.parts if p != "__init__"))
        for line, module, names in _file_imports(path):
            yield path, line, own, module, names


def _layer(part: str) -> int:
    for i, layer in enumerate(LAYERS):
        if part in layer:
            return i
    raise AssertionError(f"part {part!r} is in no layer: add it to LAYERS and to the layout in docs/layout.md")


def test_every_import_goes_down():
    bad = []
    for path, line, own, module, _ in _imports():
        target = _part(module)
        if target == own or (own in FOUNDATION and target in FOUNDATION):
            continue
        if _layer(target) >= _layer(own):
            bad.append(f"{path.relative_to(ROOT.parent)}:{line}: {own} imports {module} ({target} is not below)")
    assert not bad, "\n".join(bad)


def test_no_part_reaches_into_another_parts_privates():
    bad = []
    for path, line, own, module, names in _imports():
        target = _part(module)
        if target == own or target in FOUNDATION:
            continue
        private_module = any(p.startswith("_") for p in module.split(".")[2:])
        private_names = [n for n in names if n.startswith("_")]
        if private_module or private_names:
            bad.append(f"{path.relative_to(ROOT.parent)}:{line}: {own} imports {module} {private_names or ''}")
    assert not bad, "\n".join(bad)


def test_every_part_has_a_layer():
    parts = {p.stem if p.is_file() else p.name for p in ROOT.iterdir()
             if (p.is_dir() and (p / "__init__.py").exists()) or (p.suffix == ".py" and p.stem != "__init__")}
    for part in parts:
        _layer(part)


#: Packages whose ``__init__`` is their public API: other parts import them only as a package.
PUBLIC_API = ("model", "datasets", "sim", "excite", "ident", "design", "deploy", "diagnose", "fri", "netft", "runtime",
              "emulator", "pipeline", "fleet", "report", "testing")


def test_packages_are_imported_through_their_public_api():
    bad = []
    for path, line, own, module, _ in _imports():
        parts = module.split(".")
        if len(parts) >= 3 and parts[1] != own and parts[1] in PUBLIC_API:
            bad.append(f"{path.relative_to(ROOT.parent)}:{line}: {own} imports {module} (use iiwa_ident.{parts[1]})")
    assert not bad, "\n".join(bad)


#: Packages whose modules are all private (``_name``), behind a curated ``__init__`` (every package).
PRIVATE_MODULES = PUBLIC_API + ("description",)
#: Modules a tool names: protoc writes ``<schema>_pb2.py`` beside the schema.
GENERATED = ("fri/messages_pb2.py",)


def test_the_packages_of_private_modules_keep_them_private():
    public = [f"{p}/{m.name}" for p in PRIVATE_MODULES + ("cli",) for m in sorted((ROOT / p).glob("*.py"))
              if m.name != "__init__.py" and not m.name.startswith("_") and f"{p}/{m.name}" not in GENERATED]
    assert not public, f"a package's modules are private (_name): {public}"
    parts = {p.name for p in ROOT.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert parts == set(PRIVATE_MODULES) | {"cli"}, "every package keeps its modules private"


def test_bench_and_the_harness_use_the_public_api_only():
    # What they measure and draw is what a user runs: packages, never their modules or private names.
    files = sorted((ROOT.parent / "bench").rglob("*.py")) + sorted((ROOT / "testing").rglob("*.py"))
    assert len(files) > 20
    bad = []
    for path in files:
        for line, module, names in _file_imports(path):
            parts = module.split(".")
            if path.parent == ROOT / "testing" and parts[1:2] == ["testing"]:
                continue  # the harness's own modules
            private = [n for n in names if n.startswith("_")]
            if any(p.startswith("_") for p in parts[1:]) or private or (len(parts) >= 3 and parts[1] in PUBLIC_API):
                bad.append(f"{path.relative_to(ROOT.parent)}:{line}: imports {module} {private or ''}")
    assert not bad, "\n".join(bad)


def _module_imports() -> dict[str, set[str]]:
    """Module -> the package's modules it imports at module level, those under ``if TYPE_CHECKING`` included
    (imports inside functions are left out: they run when called, after every module is loaded)."""
    paths = {".".join(p for p in path.relative_to(ROOT.parent).with_suffix("").parts if p != "__init__"): path
             for path in ROOT.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for module, path in paths.items():
        deps: set[str] = set()

        def visit(body: list[ast.stmt], deps: set[str] = deps) -> None:
            for node in body:
                if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("iiwa_ident"):
                    for a in node.names:
                        full = f"{node.module}.{a.name}"
                        deps.add(full if full in paths else node.module)
                elif isinstance(node, ast.Import):
                    deps.update(a.name for a in node.names if a.name.startswith("iiwa_ident"))
                elif isinstance(node, ast.If | ast.Try):
                    visit(node.body)
                    visit(node.orelse)

        visit(ast.parse(path.read_text(), str(path)).body)
        graph[module] = {d for d in deps if d in paths and d != module}
    return graph


def test_no_import_circle_between_modules():
    # Not even one that exists only for the type checker: a circle says two modules are one concept.
    graph = _module_imports()
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def walk(module: str, path: list[str]) -> list[str] | None:
        state[module] = 1
        for dep in sorted(graph[module]):
            if state.get(dep) == 1:
                return path[path.index(dep):] + [dep] if dep in path else [module, dep]
            if dep not in state and (circle := walk(dep, path + [dep])):
                return circle
        state[module] = 2
        return None

    for module in sorted(graph):
        if module not in state:
            circle = walk(module, [module])
            assert circle is None, " -> ".join(circle)


#: A dataclass with this many fields or more is built by field name only (``kw_only``): a call that passes
#: them by position reads as a row of numbers and breaks silently when a field is added or moved.
KEYWORD_ONLY_FIELDS = 7


def test_wide_dataclasses_are_built_by_field_name():
    import dataclasses
    import importlib
    import inspect
    import pkgutil

    wide = []
    for info in pkgutil.walk_packages(iiwa_ident.__path__, "iiwa_ident."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if inspect.isclass(obj) and dataclasses.is_dataclass(obj) and obj.__module__ == info.name:
                fields = [f for f in dataclasses.fields(obj) if f.init]
                if len(fields) >= KEYWORD_ONLY_FIELDS and not all(f.kw_only for f in fields):
                    wide.append(f"{info.name}.{name} ({len(fields)} fields)")
    assert not wide, f"dataclasses of {KEYWORD_ONLY_FIELDS} or more fields are kw_only: {wide}"
