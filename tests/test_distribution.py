"""The wheel holds every package and every shipped data file of the source tree.

The wheel is built from a copy of the tree with the build backend the project declares, and its
contents are compared with the folders that hold an ``__init__.py`` and with the files on disk,
so that a new package or a new kind of data file cannot be left out of an installed wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCE_ROOTS = {
    "wholehand": "wholehand",
    "wholehand_plugins": "plugins",
    "wholehand_robots": "robots",
    "wholehand_objects": "objects",
}
"""Installed name -> folder: the mapping setup.py declares, written out again on purpose."""


def _source_files(folder: Path) -> list[Path]:
    return [
        p
        for p in folder.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    ]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tree = tmp_path_factory.mktemp("tree")
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, tree / name)
    for folder in SOURCE_ROOTS.values():
        shutil.copytree(ROOT / folder, tree / folder, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q"]
    subprocess.run([*cmd, "-w", str(out), str(tree)], check=True, capture_output=True)
    (built,) = out.glob("wholehand-*.whl")
    return built


@pytest.fixture(scope="module")
def wheel_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return set(archive.namelist())


def test_wheel_holds_every_package(wheel_names: set[str]) -> None:
    on_disk = {
        ".".join([name, *init.parent.relative_to(ROOT / folder).parts])
        for name, folder in SOURCE_ROOTS.items()
        for init in (ROOT / folder).rglob("__init__.py")
    }
    in_wheel = {
        n.rsplit("/", 1)[0].replace("/", ".") for n in wheel_names if n.endswith("/__init__.py")
    }
    assert "wholehand.bench" in on_disk and "wholehand_plugins.mujoco" in on_disk
    assert in_wheel == on_disk


def test_wheel_holds_every_shipped_file(wheel_names: set[str]) -> None:
    expected = {
        "/".join([name, *path.relative_to(ROOT / folder).parts])
        for name, folder in SOURCE_ROOTS.items()
        for path in _source_files(ROOT / folder)
    }
    assert "wholehand/py.typed" in expected
    assert "wholehand_robots/allegro_right/hand.toml" in expected
    assert sorted(expected - wheel_names) == []


def test_wheel_declares_the_command_and_every_plugin(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        text = archive.read("wholehand-0.1.0.dist-info/entry_points.txt").decode()
    assert "wholehand = wholehand.cli.main:main" in text
    for group in ("contact_estimators", "allocators", "reachers", "backends"):
        assert f"[wholehand.{group}]" in text
    for name, module in [("qp", "qp"), ("mujoco", "mujoco.backend"), ("mink", "mink_reacher")]:
        assert f"{name} = wholehand_plugins.{module}:" in text
