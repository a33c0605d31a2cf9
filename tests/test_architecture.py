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



def test_no_public_function_is_longer_than_100_lines():
    import inspect

    long = []
    for qual, func in _public_functions():
        lines, _ = inspect.getsourcelines(func)
        if len(lines) > 100 and qual not in EXEMPT_LENGTH:
            long.append(f"{qual} ({len(lines)} lines)")
    assert not long, f"public functions longer than 100 lines: {long}"


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
