"""Rules of the house that code can check (ARCHITECTURE.md)."""

import ast
from pathlib import Path

import numpy as np
import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lsmta"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
    return names


def test_library_never_imports_the_generator():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        if {"synth", "evaluation"} & set(path.relative_to(PACKAGE).parts):
            continue
        if any("synth" in name.split(".") for name in _imports(path)):
            offenders.append(str(path.relative_to(PACKAGE)))
    assert not offenders, f"library modules importing lsmta.synth: {offenders}"


def test_systems_never_see_the_truth():
    """A system runs from what a user has: it imports neither the generator nor the
    evaluation code, not even indirectly through a module of its own package."""
    offenders = []
    for path in (PACKAGE / "systems").rglob("*.py"):
        names = _imports(path)
        if any({"synth", "evaluation"} & set(name.split(".")) for name in names):
            offenders.append(str(path.relative_to(PACKAGE)))
    assert (PACKAGE / "systems" / "__init__.py").exists()
    assert not offenders, f"lsmta.systems modules importing synth or evaluation: {offenders}"


def test_every_built_module_is_on_the_map():
    text = (PACKAGE.parent / "ARCHITECTURE.md").read_text(encoding="utf-8")
    for path in PACKAGE.rglob("*.py"):
        if path.name == "__init__.py":
            continue
        assert path.name in text, f"{path.relative_to(PACKAGE)} is missing from ARCHITECTURE.md"


# ---------------------------------------------------------------------- house style
# Modules whose conventions are owned by other open work (see ARCHITECTURE.md, house style):
# they join these checks when that work lands.
EXEMPT_MODULES: set = set()
EXEMPT_RNG: set = set()
# the notebooks' vocabulary: record(figure, quantity, value, unit), verdict(ok, target); and
# the command line's entry point
EXEMPT_ARGS = {"lsmta.report.record(unit)", "lsmta.report.verdict(target)", "lsmta.cli.main(argv)"}
EXEMPT_LENGTH: set = set()


def _modules():
    import importlib
    import pkgutil

    import lsmta

    for info in pkgutil.walk_packages(lsmta.__path__, "lsmta."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        if info.name in EXEMPT_MODULES:
            continue
        yield importlib.import_module(info.name)


def _public_functions():
    """(qualified name, function) of every public function and public method defined in
    a public module of lsmta."""
    import inspect

    for module in _modules():
        for name, obj in vars(module).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj):
                yield f"{module.__name__}.{name}", obj
            elif inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if attr.startswith("_"):
                        continue
                    func = getattr(member, "__func__", member)
                    if inspect.isfunction(func):
                        yield f"{module.__name__}.{name}.{attr}", func


def test_tuning_arguments_are_keyword_only():
    import inspect

    offenders = []
    for qual, func in _public_functions():
        for p in inspect.signature(func).parameters.values():
            if p.default is not p.empty and p.kind is not p.KEYWORD_ONLY \
                    and qual not in EXEMPT_RNG and f"{qual}({p.name})" not in EXEMPT_ARGS:
                offenders.append(f"{qual}({p.name})")
    assert not offenders, f"arguments with defaults taken positionally: {offenders}"


def test_rng_arguments_are_keyword_only_generator_int_or_none():
    import inspect

    from lsmta._validate import as_rng

    offenders = []
    for qual, func in _public_functions():
        p = inspect.signature(func).parameters.get("rng")
        if p is not None and qual not in EXEMPT_RNG and (p.kind is not p.KEYWORD_ONLY
                                                         or p.default is not None):
            offenders.append(qual)
    assert not offenders, f"rng not keyword-only with default None: {offenders}"
    g = np.random.default_rng(1)
    assert as_rng(g) is g
    assert as_rng(5).integers(1 << 30) == np.random.default_rng(5).integers(1 << 30)
    assert isinstance(as_rng(None), np.random.Generator)
    with pytest.raises(TypeError, match="rng"):
        as_rng("5")


def test_statuses_are_int_enums():
    import enum
    import inspect

    statuses, bare = [], []
    for module in _modules():
        for name, obj in vars(module).items():
            if inspect.isclass(obj) and name.endswith("Status"):
                statuses.append(obj)
                assert issubclass(obj, enum.IntEnum), f"{module.__name__}.{name} is no IntEnum"
            elif name.upper().startswith("STATUS") and isinstance(obj, int | str | dict):
                bare.append(f"{module.__name__}.{name}")
    assert not bare, f"status codes outside an IntEnum: {bare}"
    names = {s.__name__ for s in statuses}
    assert {"TrackStatus", "MarkerStatus", "TargetStatus", "FitStatus", "Status"} <= names



MAX_LINES = 80
MAX_PARAMETERS = 12
# public functions that keep **kwargs, each with its reason
EXEMPT_KWARGS = {
    "lsmta.camera.Camera.replace": "mirrors dataclasses.replace over the camera's 16 fields, "
                                   "each checked again by __post_init__",
    "lsmta.pantilt.model.PanTiltCamera.replace": "mirrors dataclasses.replace; unknown names "
                                                 "are refused and the model checked again",
}
DEFERRED = "# deferred:"  # the marker of an import left inside a function on purpose


def test_no_public_function_is_longer_than_80_lines():
    import inspect

    long = []
    for qual, func in _public_functions():
        lines, _ = inspect.getsourcelines(func)
        if len(lines) > MAX_LINES and qual not in EXEMPT_LENGTH:
            long.append(f"{qual} ({len(lines)} lines)")
    assert not long, f"public functions longer than {MAX_LINES} lines: {long}"


def test_public_functions_take_no_loose_keywords():
    """No ``**kwargs`` forwarded unchecked: tuning goes in a ``...Params`` dataclass."""
    import inspect

    offenders = []
    for qual, func in _public_functions():
        if any(p.kind is p.VAR_KEYWORD for p in inspect.signature(func).parameters.values()) \
                and qual not in EXEMPT_KWARGS:
            offenders.append(qual)
    assert not offenders, f"public functions with **kwargs: {offenders}"


def test_public_functions_take_at_most_12_parameters():
    import inspect

    offenders = []
    for qual, func in _public_functions():
        params = [p for p in inspect.signature(func).parameters.values()
                  if p.name not in ("self", "cls")]
        if len(params) > MAX_PARAMETERS:
            offenders.append(f"{qual} ({len(params)})")
    assert not offenders, f"public functions with more than {MAX_PARAMETERS} parameters: " \
                          f"{offenders}"


def _public_module_files():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).parts
        if not any(part.startswith("_") and part != "__init__.py" for part in parts):
            yield path


def test_every_public_name_has_one_owner():
    """No public class or function name is defined in two modules of lsmta."""
    owners: dict[str, list[str]] = {}
    for path in _public_module_files():
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.FunctionDef | ast.ClassDef) and not node.name.startswith("_"):
                owners.setdefault(node.name, []).append(str(path.relative_to(PACKAGE)))
    twice = {name: where for name, where in owners.items() if len(where) > 1}
    assert not twice, f"public names defined in more than one module: {twice}"


def test_imports_sit_at_the_top():
    """Imports inside functions hide dependencies and cycles; the only exception is a
    heavy optional dependency deferred on purpose, marked ``# deferred: <why>``."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for sub in ast.walk(node):
                if isinstance(sub, ast.Import | ast.ImportFrom):
                    span = lines[sub.lineno - 1:sub.end_lineno]
                    if not any(DEFERRED in line for line in span):
                        offenders.append(f"{path.relative_to(PACKAGE)}:{sub.lineno}")
    assert not sorted(set(offenders)), f"imports inside functions: {sorted(set(offenders))}"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_import_cycles():
    """The modules of lsmta (packages' ``__init__`` aside) import each other without a
    cycle, counting every import wherever it sits."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        if path.name == "__init__.py":
            continue
        package = name.rsplit(".", 1)[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                    base = f"{base}.{node.module}" if node.module else base
                else:
                    base = node.module or ""
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            for t in targets:
                if t in modules and modules[t].name != "__init__.py" and t != name:
                    edges.add(t)
        graph[name] = edges
    state: dict[str, int] = {}
    cycles = []

    def visit(node, stack):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, f"import cycles: {cycles}"


def test_settings_are_params_dataclasses():
    """Settings bundles are named ``...Params`` (not ``...Settings``, ``...Options``)."""
    offenders = []
    for path in _public_module_files():
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_") \
                    and node.name.endswith(("Settings", "Options", "Config")):
                offenders.append(f"{path.relative_to(PACKAGE)}:{node.name}")
    assert not offenders, f"settings classes not named ...Params: {offenders}"


def test_results_are_built_by_keyword():
    """No dataclass of lsmta is constructed with more than two positional arguments."""
    dataclasses, plain = set(), set()
    trees = {p: ast.parse(p.read_text(encoding="utf-8")) for p in PACKAGE.rglob("*.py")}
    for tree in trees.values():
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                is_dc = any("dataclass" in ast.unparse(d) for d in node.decorator_list)
                (dataclasses if is_dc else plain).add(node.name)
    names = dataclasses - plain          # a name also used by a plain class is ambiguous
    exempt = {m.replace(".", "/") + ".py" for m in EXEMPT_MODULES}
    offenders = []
    for path, tree in trees.items():
        rel = str(path.relative_to(PACKAGE.parent))
        if rel in exempt:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id in names and len(node.args) > 2:
                offenders.append(f"{rel}:{node.lineno} {node.func.id}")
    assert not offenders, f"dataclasses built from positional arguments: {offenders}"


def test_no_private_name_crosses_a_package():
    """A private (``_name``) function, class or module of one package is not imported by
    another; what packages share lives in ``lsmta/_validate.py`` or is made public."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        name = _module_name(path)
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                module = f"{base}.{node.module}" if node.module else base
            elif (node.module or "").startswith("lsmta"):
                module = node.module
            else:
                continue
            for alias in node.names:
                parts = f"{module}.{alias.name}".split(".")
                private = [i for i, p in enumerate(parts) if p.startswith("_")
                           and p not in ("_validate", "__init__")]
                if not private:
                    continue
                home = ".".join(parts[:private[0]])     # what holds the private name ...
                if not (PACKAGE.parent / home.replace(".", "/")).is_dir():
                    home = home.rsplit(".", 1)[0]       # ... a module: its package
                if not (package == home or package.startswith(home + ".")):
                    offenders.append(f"{path.relative_to(PACKAGE)}: {'.'.join(parts)}")
    assert not offenders, f"private names imported across packages: {offenders}"


def test_real_data_studies_never_see_the_generator():
    """lsmta.real (studies of real recordings) and the loaders it uses import neither the
    generator nor the controlled studies, directly or through any module they load."""
    import subprocess
    import sys

    offenders = [str(p.relative_to(PACKAGE)) for p in (PACKAGE / "real").rglob("*.py")
                 if any({"synth", "evaluation"} & set(n.split(".")) for n in _imports(p))]
    assert not offenders, f"lsmta.real modules importing synth or evaluation: {offenders}"
    names = ["lsmta.data"] + [f"lsmta.real.{p.stem}" for p in (PACKAGE / "real").glob("*.py")
                              if p.stem != "__init__"]
    code = ("import importlib, sys\n"
            f"for name in {names!r}:\n    importlib.import_module(name)\n"
            "print(sorted(m for m in sys.modules if m.startswith(('lsmta.synth', "
            "'lsmta.evaluation'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=PACKAGE.parent, check=True).stdout.strip()
    assert out == "[]", f"importing lsmta.real loads {out}"
