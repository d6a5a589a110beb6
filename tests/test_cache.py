"""The on-disk cache never stops a command: damaged entries are recomputed, an unusable folder is
skipped, each with a warning that names the path and the fix."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from wholehand.models import cache
from wholehand.models.objects import ObjectModel
from wholehand.models.sdf import SignedDistanceGrid


def _sphere_grid() -> SignedDistanceGrid:
    return ObjectModel.sphere(0.03, mass=0.1).sdf


def _entry(folder):
    (path,) = (folder / "sdf").glob("*.npz")
    return path


@pytest.mark.parametrize(
    "damage",
    ["truncated", "empty", "not_a_zip", "wrong_keys"],
)
def test_a_damaged_entry_is_recomputed_with_a_warning(fresh_cache, caplog, damage):
    good = _sphere_grid()
    path = _entry(fresh_cache)
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "not_a_zip":
        path.write_bytes(b"this is not an npz file at all")
    else:
        np.savez(path.with_suffix(""), other=np.zeros(3))  # writes <key>.npz
    with caplog.at_level(logging.WARNING, logger="wholehand.models.cache"):
        again = _sphere_grid()
    np.testing.assert_array_equal(again.values, good.values)
    assert str(path) in caplog.text and "recomputing it" in caplog.text
    # ... and the entry was rewritten: the next load is a clean hit.
    caplog.clear()
    assert cache.load_arrays("sdf", path.stem, ("origin", "spacing", "values")) is not None
    assert caplog.text == ""


def test_an_unusable_cache_folder_is_skipped_with_the_fix_named(tmp_path, monkeypatch, caplog):
    blocker = tmp_path / "cache-is-a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("WHOLEHAND_CACHE", str(blocker))
    monkeypatch.setattr(cache, "_warned_folders", set())
    with caplog.at_level(logging.WARNING, logger="wholehand.models.cache"):
        grid = _sphere_grid()
        _sphere_grid()
    assert grid.values.size > 0
    assert caplog.text.count("cannot be used") == 1  # reported once
    assert "set WHOLEHAND_CACHE to a writable folder" in caplog.text
    assert cache.save_arrays("sdf", "k", {"a": np.zeros(1)}) is None
    assert cache.load_arrays("sdf", "k") is None


def test_text_files_written_at_once_by_two_workers_do_not_share_a_temporary_file(
    tmp_path, monkeypatch
):
    # Study workers load the same assembly at once. Writing through one fixed temporary name
    # let one worker move the other's file away before its rename (FileNotFoundError). A folder
    # in the place of that fixed name stands in for the other worker's file deterministically.
    monkeypatch.setenv("WHOLEHAND_CACHE", str(tmp_path))
    text = "<robot name='r'/>"
    first = cache.text_file("assemblies", "r", text, "urdf")
    first.unlink()
    first.with_suffix(".tmp").mkdir()
    again = cache.text_file("assemblies", "r", text, "urdf")
    assert again == first and again.read_text() == text
    assert not list(again.parent.glob("*.tmp.*")) and not list(
        again.parent.glob(f"{again.name}*.tmp")
    )
