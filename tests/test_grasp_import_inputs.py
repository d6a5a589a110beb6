"""Grasp files from other labs, read as a careless or hostile sender writes them: nothing in a
file runs, nothing not finite or not a pose is written, and every malformed field is named."""

from __future__ import annotations

import json
import os
import pickle
import re

import numpy as np
import pytest

from wholehand.cli.main import main
from wholehand.errors import ConfigError
from wholehand.grasps.importers import import_grasps
from wholehand.grasps.npy_reader import load_npy
from wholehand.grasps.store import load_grasps

OBJECT = "077_rubiks_cube"
IDENTITY = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]


class _WritesMarker:
    """Unpickling this calls ``os.system``: what a crafted grasp file would do."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _dexonomy(allegro, rows, **fields):
    """A Dexonomy dict: ``rows`` of 7 root values each, the joints of a shipped grasp."""
    q = load_grasps("allegro_right", OBJECT)[0].q
    joints = [q[name] for name in allegro.joint_names]
    data = {
        "grasp_qpos": np.array([[*r, *joints] for r in rows], dtype=float),
        "obj_pose": np.array(IDENTITY),
        "obj_scale": 1.0,
        "joint_names": list(allegro.joint_names),
    }
    data.update(fields)
    return data


def _save(tmp_path, data, name="g.npy"):
    path = tmp_path / name
    np.save(path, data, allow_pickle=True)
    return path


def test_a_crafted_file_runs_nothing_and_is_named(tmp_path, allegro):
    marker = tmp_path / "marker"
    payload = [{"qpos": {"a": 1.0}, "scale": 1.0, "note": _WritesMarker(marker)}]
    path = _save(tmp_path, np.array(payload, dtype=object))
    assert not marker.exists()
    with pytest.raises(ConfigError, match=r"posix\.system.*nothing in it was run"):
        import_grasps(allegro, [path], "dexgraspnet")
    with pytest.raises(ConfigError, match="nothing in it was run"):
        import_grasps(allegro, [path], "dexonomy")
    assert not marker.exists()
    # The marker proves the payload would run under np.load(allow_pickle=True).
    np.load(path, allow_pickle=True)
    assert marker.exists()


def test_the_reader_gives_what_np_load_gives_for_every_pickle_protocol(tmp_path):
    data = {"a": np.arange(6.0).reshape(2, 3), "b": [np.float32(2.5), np.int64(3), "x"]}
    array = np.array([data], dtype=object)
    for protocol in (2, 3, 4, 5):
        path = tmp_path / f"p{protocol}.npy"
        with open(path, "wb") as f:
            header = {"descr": "|O", "fortran_order": False, "shape": (1,)}
            np.lib.format.write_array_header_1_0(f, header)
            pickle.dump(array, f, protocol=protocol)
        (got,) = load_npy(path)
        np.testing.assert_array_equal(got["a"], data["a"])
        assert got["b"] == [2.5, 3, "x"]
    plain = tmp_path / "plain.npy"
    np.save(plain, np.eye(3))
    np.testing.assert_array_equal(load_npy(plain), np.eye(3))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "not a NumPy .npy file"),
        (b"\x93NUMPY\x01\x00garbage", "not a NumPy .npy file"),
        (None, "damaged"),  # a valid header, the pickle cut in half
    ],
)
def test_damaged_files_are_named(tmp_path, allegro, content, message):
    path = tmp_path / "bad.npy"
    if content is None:
        whole = _save(tmp_path, _dexonomy(allegro, [IDENTITY]), "whole.npy").read_bytes()
        content = whole[: len(whole) // 2]
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message):
        import_grasps(allegro, [path], "dexonomy")


@pytest.mark.parametrize(
    ("root", "reason"),
    [
        ([np.nan, 0, 0, 1, 0, 0, 0], "hand root not finite"),
        ([0, 0, np.inf, 1, 0, 0, 0], "hand root not finite"),
        ([0, 0, 0, 0.9, 0, 0, 0], "hand root quaternion of norm 0.9, not 1"),
        ([0, 0, 0, 0, 0, 0, 0], "hand root quaternion of norm 0, not 1"),
    ],
)
def test_grasps_that_are_not_poses_are_skipped_with_the_reason(tmp_path, allegro, root, reason):
    path = _save(tmp_path, _dexonomy(allegro, [IDENTITY, root]))
    grasps, record = import_grasps(allegro, [path], "dexonomy")
    assert len(grasps) == 1
    assert record["skipped"] == {reason: 1}


def test_an_object_pose_or_joint_not_finite_is_skipped(tmp_path, allegro):
    obj = _save(tmp_path, _dexonomy(allegro, [IDENTITY], obj_pose=[0, np.nan, 0, 1, 0, 0, 0]))
    assert import_grasps(allegro, [obj], "dexonomy")[1]["skipped"] == {"object pose not finite": 1}
    data = _dexonomy(allegro, [IDENTITY])
    data["grasp_qpos"][0, 9] = np.nan
    joint = allegro.joint_names[2]
    grasps, record = import_grasps(allegro, [_save(tmp_path, data)], "dexonomy")
    assert grasps == []
    assert record["skipped"] == {f"joint {joint!r} angle not finite (nan)": 1}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"grasp_qpos": {"a": 1}}, r"g\.npy: grasp_qpos is not numbers"),
        ({"grasp_qpos": [["x"] * 23]}, r"g\.npy: grasp_qpos is not numbers"),
        ({"grasp_qpos": np.zeros((2, 2, 23))}, r"grasp_qpos has shape \(2, 2, 23\)"),
        ({"grasp_qpos": np.zeros(5)}, r"grasp_qpos has shape \(1, 5\)"),
        ({"obj_pose": [0, 0, 1]}, r"obj_pose has shape \(1, 3\)"),
        ({"obj_pose": "here"}, "obj_pose is not numbers"),
        ({"obj_scale": []}, "obj_scale has 0 rows for 1 grasps"),
        ({"pregrasp_qpos": np.zeros((1, 8))}, r"pregrasp_qpos has shape \(1, 8\)"),
    ],
)
def test_malformed_dexonomy_fields_are_named(tmp_path, allegro, change, message):
    path = _save(tmp_path, _dexonomy(allegro, [IDENTITY], **change))
    with pytest.raises(ConfigError, match=message):
        import_grasps(allegro, [path], "dexonomy")


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"qpos": [1.0, 2.0], "scale": 1.0}, r"g\.npy\[0\]: qpos is a list, expected a dict"),
        ({"qpos": {"WRJTx": "far"}, "scale": 1.0}, r"g\.npy\[0\]: qpos\['WRJTx'\] is not num"),
        ({"qpos": {"WRJTx": 0.0}, "scale": [1.0, 2.0]}, r"g\.npy\[0\]: scale has shape \(2,\)"),
    ],
)
def test_malformed_dexgraspnet_entries_are_named(tmp_path, allegro, entry, message):
    path = _save(tmp_path, np.array([entry], dtype=object))
    with pytest.raises(ConfigError, match=message):
        import_grasps(allegro, [path], "dexgraspnet")


def test_malformed_bodex_fields_are_named(tmp_path, allegro):
    poses = np.zeros((1, 1, 2, 7 + len(allegro.joint_names)))
    poses[..., 3] = 1.0
    for change, message in [
        ({"obj_pose": np.zeros((2, 7))}, r"obj_pose has shape \(2, 7\)"),
        ({"obj_scale": np.array([])}, r"obj_scale has shape \(0,\)"),
        ({"robot_pose": "poses"}, "robot_pose is not numbers"),
    ]:
        data = {"robot_pose": poses, "obj_pose": np.array([IDENTITY]), "obj_scale": [1.0]}
        data["joint_names"] = list(allegro.joint_names)
        data.update(change)
        with pytest.raises(ConfigError, match=message):
            import_grasps(allegro, [_save(tmp_path, data)], "bodex")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--object-scale", "nan"], "--object-scale nan: give the mesh scale"),
        (["--object-scale", "-1"], "--object-scale -1.0: give the mesh scale"),
        (["--root-offset", "0 0 0 0 0 0 0"], "quaternion of norm 0, not 1"),
        (["--root-offset", "0 0 nan 1 0 0 0"], "--root-offset: .* pose not finite"),
        (["--root-offset", "1 2 3"], "is not seven numbers"),
    ],
)
def test_bad_import_options_are_refused(tmp_path, allegro, capsys, extra, message):
    path = _save(tmp_path, _dexonomy(allegro, [IDENTITY]))
    args = ["grasps", "import", str(path), "--format", "dexonomy", "--object", OBJECT]
    assert main([*args, "--out", str(tmp_path / "out"), *extra]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert re.search(message, err), err
    assert not (tmp_path / "out").exists()


def test_an_object_that_does_not_exist_is_refused_before_reading(tmp_path, capsys):
    args = ["grasps", "import", str(tmp_path / "none.npy"), "--format", "dexonomy"]
    assert main([*args, "--object", "077_rubiks_cub", "--out", str(tmp_path)]) == 2
    assert "unknown object '077_rubiks_cub'" in capsys.readouterr().err


def test_what_is_written_is_strict_json(tmp_path, allegro, capsys):
    rows = [IDENTITY, [np.nan, 0, 0, 1, 0, 0, 0], [0, 0, 0, 2.0, 0, 0, 0]]
    path = _save(tmp_path, _dexonomy(allegro, rows))
    args = ["grasps", "import", str(path), "--format", "dexonomy", "--object", OBJECT]
    assert main([*args, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "1 of 3 grasps" in out and "hand root not finite" in out
    text = (tmp_path / f"{OBJECT}.json").read_text()
    json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in a grasp file"))
