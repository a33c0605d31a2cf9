"""Rules of the house that code can check (ARCHITECTURE.md)."""

import ast
from pathlib import Path

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
