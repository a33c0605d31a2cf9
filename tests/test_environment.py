"""The pinned environment: requirements.lock pins every dependency that pyproject.toml
names (and its test extra), within the ranges it allows; environment.yml and the bootstrap
install from the lock."""

import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement

tomllib = pytest.importorskip("tomllib")       # Python 3.11+

ROOT = Path(__file__).resolve().parents[1]


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _lock() -> dict:
    pins = {}
    for line in (ROOT / "requirements.lock").read_text(encoding="utf-8").splitlines():
        m = re.match(r"([A-Za-z0-9_.\-]+)==(\S+)", line)
        if m:
            pins[_norm(m.group(1))] = m.group(2)
    return pins


def _wanted():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    return [Requirement(r) for r in
            project["dependencies"] + project["optional-dependencies"]["test"]]


@pytest.mark.parametrize("req", _wanted(), ids=str)
def test_lock_pins_every_dependency_within_its_range(req):
    if req.marker is not None and not req.marker.evaluate():
        pytest.skip(f"{req} does not apply to this Python (the lock is made for 3.11)")
    pins = _lock()
    assert _norm(req.name) in pins, f"{req.name} is not in requirements.lock: re-run pip-compile"
    assert req.specifier.contains(pins[_norm(req.name)], prereleases=True), (
        f"{req.name}=={pins[_norm(req.name)]} is outside {req.specifier}")


def test_environment_yml_and_bootstrap_install_from_the_lock():
    env = (ROOT / "environment.yml").read_text(encoding="utf-8")
    assert "-r requirements.lock" in env and "--no-deps -e ." in env
    boot = (ROOT / "scripts" / "bootstrap.sh").read_text(encoding="utf-8")
    assert "-r requirements.lock" in boot and "--no-deps -e ." in boot
