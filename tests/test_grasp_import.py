"""Grasp files of DexGraspNet, Dexonomy and BODex, written to their specification, imported."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from wholehand.cli.main import main
from wholehand.errors import ConfigError
from wholehand.grasps.importers import import_grasps
from wholehand.grasps.store import load_grasps

OBJECT = "077_rubiks_cube"


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _quat_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation of a unit quaternion, written out."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _xyz_wxyz(M: np.ndarray) -> list[float]:
    x, y, z, w = Rotation.from_matrix(M[:3, :3]).as_quat()
    return [*M[:3, 3], w, x, y, z]


@pytest.fixture(scope="module")
def shipped(allegro):
    """Two shipped Allegro grasps of the cube: the ground truth every file encodes."""
    return load_grasps("allegro_right", OBJECT)[:2]


@pytest.fixture(scope="module")
def world_object():
    """The object's world pose of the Dexonomy and BODex files: a quaternion's rotation."""
    q = np.array([0.8, 0.1, -0.5, 0.3])
    q /= np.linalg.norm(q)
    wMo = np.eye(4)
    wMo[:3, :3] = _quat_matrix(*q)
    wMo[:3, 3] = [0.3, -0.2, 0.75]
    return wMo, [*wMo[:3, 3], *q]


def _check(grasps, shipped, hand):
    assert len(grasps) == len(shipped)
    for got, want in zip(grasps, shipped, strict=True):
        np.testing.assert_allclose(got.oMb, want.oMb, atol=1e-9)
        assert got.q == pytest.approx({n: want.q[n] for n in hand.joint_names}, abs=1e-12)


def test_dexgraspnet_files_keep_pose_and_joints_and_skip_other_scales(tmp_path, allegro, shipped):
    entries = []
    for g in shipped:
        R = g.oMb[:3, :3]
        # Static x-y-z Euler angles (transforms3d's sxyz): R = Rz(c) Ry(b) Rx(a).
        b = -np.arcsin(R[2, 0])
        a, c = np.arctan2(R[2, 1], R[2, 2]), np.arctan2(R[1, 0], R[0, 0])
        assert np.allclose(
            _axis_rotation(2, c) @ _axis_rotation(1, b) @ _axis_rotation(0, a), R, atol=1e-12
        )
        root = dict(zip(("WRJTx", "WRJTy", "WRJTz"), g.oMb[:3, 3], strict=True))
        root.update(WRJRx=a, WRJRy=b, WRJRz=c)
        entries.append({"scale": 1.0, "qpos": {**g.q, **root}, "energy": 1.0})
    entries.append({"scale": 0.08, "qpos": entries[0]["qpos"], "energy": 1.0})
    path = tmp_path / "cube.npy"
    np.save(path, entries, allow_pickle=True)
    grasps, record = import_grasps(allegro, [path], "dexgraspnet")
    _check(grasps, shipped, allegro)
    assert record["read"] == 3 and record["skipped"] == {"made on the object at scale 0.08": 1}
    # Only the other scale wanted: nothing fits, and the scales found are named.
    with pytest.raises(ConfigError, match=r"scale 0\.5.*\[0\.08, 1\.0\]"):
        import_grasps(allegro, [path], "dexgraspnet", object_scale=0.5)


def test_dexonomy_files_map_the_world_into_the_object_frame(
    tmp_path, allegro, shipped, world_object
):
    wMo, obj_pose = world_object
    names = list(reversed(allegro.joint_names))  # the file's own order
    paths = []
    for k, g in enumerate(shipped):
        grasp = [*_xyz_wxyz(wMo @ g.oMb), *[g.q[n] for n in names]]
        pre_oMb = g.oMb.copy()
        pre_oMb[:3, 3] += [0.0, 0.0, 0.05]
        pre = [*_xyz_wxyz(wMo @ pre_oMb), *[0.0 for _ in names]]
        data = {
            "grasp_qpos": np.array(grasp),
            "pregrasp_qpos": np.array(pre),
            "squeeze_qpos": np.array(grasp),
            "obj_pose": np.array(obj_pose),
            "obj_scale": 1.0,
            "obj_path": "assets/object/cube",
        }
        if k == 0:
            data["joint_names"] = names
        paths.append(tmp_path / f"{k}.npy")
        np.save(paths[-1], data)
    with pytest.raises(ConfigError, match="--joint-names"):
        import_grasps(allegro, paths, "dexonomy")  # the second file names no joints
    grasps, _ = import_grasps(allegro, paths, "dexonomy", joint_names=names)
    _check(grasps, shipped, allegro)
    pre_expected = shipped[0].oMb.copy()
    pre_expected[:3, 3] += [0.0, 0.0, 0.05]
    np.testing.assert_allclose(grasps[0].extra["pregrasp_oMb"], pre_expected, atol=1e-9)
    assert set(grasps[0].extra["pregrasp_q"].values()) == {0.0}


def test_bodex_files_with_renamed_joints_and_a_root_offset(
    tmp_path, allegro, shipped, world_object
):
    wMo, obj_pose = world_object
    theirs = [f"j{i}" for i in range(len(allegro.joint_names))]
    rename = dict(zip(theirs, allegro.joint_names, strict=True))
    # The file's root sits 2 cm along the base's z and turned 90 deg about it: rMb.
    rMb = np.eye(4)
    rMb[:3, :3] = _axis_rotation(2, np.pi / 2)
    rMb[:3, 3] = [0.0, 0.0, -0.02]
    rows = []
    for g in shipped:
        oMr = g.oMb @ np.linalg.inv(rMb)
        joints = [g.q[rename[t]] for t in theirs]
        rows.append([[*_xyz_wxyz(wMo @ oMr), *joints], [*_xyz_wxyz(wMo @ oMr), *joints]])
    data = {
        "robot_pose": np.array([rows]),
        "obj_pose": np.array([obj_pose]),
        "obj_scale": np.array([1.0]),
    }
    path = tmp_path / "cube_grasp.npy"
    np.save(path, data)
    with pytest.raises(ConfigError, match="--joint-map"):
        import_grasps(allegro, [path], "bodex", joint_names=theirs)
    grasps, _ = import_grasps(
        allegro, [path], "bodex", joint_names=theirs, joint_map=rename, root_offset=rMb
    )
    _check(grasps, shipped, allegro)


def test_a_grasp_past_a_joint_limit_is_skipped_with_its_joint(tmp_path, allegro, shipped):
    g = shipped[0]
    R = g.oMb[:3, :3]
    root = dict(zip(("WRJTx", "WRJTy", "WRJTz"), g.oMb[:3, 3], strict=True))
    a, b, c = Rotation.from_matrix(R).as_euler("xyz")
    root.update(WRJRx=a, WRJRy=b, WRJRz=c)
    bad = {**g.q, "joint_1.0": 5.0}
    path = tmp_path / "cube.npy"
    np.save(
        path, [{"scale": 1.0, "qpos": {**g.q, **root}}, {"scale": 1.0, "qpos": {**bad, **root}}]
    )
    grasps, record = import_grasps(allegro, [path], "dexgraspnet")
    assert len(grasps) == 1
    (reason,) = record["skipped"]
    assert "joint 'joint_1.0' outside its limits" in reason


@pytest.mark.parametrize(
    ("content", "fmt", "message"),
    [
        ({"something": 1}, "dexonomy", "expected the keys 'grasp_qpos' and 'obj_pose'"),
        ({"robot_pose": np.zeros((1, 2, 1, 5)), "obj_pose": np.zeros(7)}, "bodex", "shape"),
        ([1, 2, 3], "dexgraspnet", "not a DexGraspNet grasp file"),
    ],
)
def test_files_that_are_not_of_the_format_are_named(tmp_path, allegro, content, fmt, message):
    path = tmp_path / "bad.npy"
    np.save(path, content, allow_pickle=True)
    with pytest.raises(ConfigError, match=message):
        import_grasps(allegro, [path], fmt)


def test_the_import_command_writes_a_grasp_file_the_runs_read(
    tmp_path, allegro, shipped, world_object, capsys
):
    wMo, obj_pose = world_object
    names = allegro.joint_names
    g = shipped[0]
    data = {
        "grasp_qpos": np.array([*_xyz_wxyz(wMo @ g.oMb), *[g.q[n] for n in names]]),
        "obj_pose": np.array(obj_pose),
        "obj_scale": 1.0,
    }
    path = tmp_path / "0.npy"
    np.save(path, data)
    args = ["grasps", "import", str(path), "--format", "dexonomy", "--object", OBJECT]
    args += ["--joint-names", ",".join(names), "--out", str(tmp_path / "out")]
    assert main(args) == 0
    assert "1 of 1 grasps ->" in capsys.readouterr().out
    (got,) = load_grasps(tmp_path / "out" / f"{OBJECT}.json")
    np.testing.assert_allclose(got.oMb, g.oMb, atol=1e-9)
    np.testing.assert_allclose(got.q_array(allegro), g.q_array(allegro), atol=1e-9)
    assert main([*args[:-2], "--joint-map", "nonsense"]) == 2
    assert "--joint-map: 'nonsense' is not their=ours" in capsys.readouterr().err
