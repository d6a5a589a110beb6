"""An MJCF hand from a registry wheel, by config alone, and the MJCF file handling behind it."""

from __future__ import annotations

import shutil
import textwrap
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from toy_hand import write_toy_hand
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.backends.command import Command
from wholehand.errors import ConfigError
from wholehand.grasps.generate import generate_grasps
from wholehand.grasps.store import save_grasps
from wholehand.models.hand import load_hand
from wholehand.models.mjcf_file import mjcf_for_parsers
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.studies.base import TINY_PROTOCOL
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec, run_trial

SHADOW = Path(__file__).resolve().parents[1] / "examples" / "hands" / "shadow_hand_gymnasium"


@pytest.fixture(scope="module")
def shadow(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hands") / "shadow"
    shutil.copytree(SHADOW, folder)
    return load_hand(folder)


def test_the_shadow_hand_of_gymnasium_robotics_loads_from_the_installed_wheel(shadow):
    assert "site-packages" in str(shadow.config.model_path) or "dist-packages" in str(
        shadow.config.model_path
    )
    assert shadow.nq == 22 and shadow.n_actuation == 22  # 24 joints, the wrist's 2 locked
    assert shadow.joint_names[0] == "robot0:FFJ3" and shadow.joint_names[-1] == "robot0:THJ0"
    assert "robot0:palm" in shadow.link_names and "robot0:forearm" not in shadow.link_names
    # The scene file's floor body is gone, its hand kept, in the file Pinocchio read.
    flat = mjcf_for_parsers(shadow.config)
    assert flat != shadow.config.model_path
    roots = [b.name for b in mujoco.MjSpec.from_file(str(flat)).worldbody.bodies]
    assert roots == ["robot0:hand mount"]


def test_its_scene_drops_the_locked_wrists_tendons_and_closes_the_fingers(shadow):
    backend = MujocoBackend(shadow, ObjectModel.sphere(0.03, mass=0.1))
    source = mujoco.MjModel.from_xml_path(str(shadow.config.model_path))
    assert backend.model.nu == 22 and backend.model.ntendon == source.ntendon - 4
    q0 = backend.observe().q
    flex = np.array([n[-2:] in ("J2", "J1", "J0") and "TH" not in n for n in shadow.joint_names])
    backend.apply(Command(np.where(flex, 0.05, 0.0)))
    backend.step(0.5)
    assert (backend.observe().q[flex] > q0[flex] + 0.05).all()  # every finger curls
    assert not any(backend.warnings().values())


def test_it_grasps_and_holds_a_cube(shadow, tmp_path):
    """From a generated grasp through the shortened perturbation protocol (60 deg pull)."""
    cube = load_object("077_rubiks_cube")
    grasps, info = generate_grasps(shadow, cube, count=1, seed=0, max_candidates=40)
    assert len(grasps) == 1, info["rejected"]
    path = save_grasps(tmp_path / "077_rubiks_cube.json", shadow.name, cube.name, grasps, info)
    spec = TrialSpec(
        hand=str(shadow.config.path.parent),
        object=cube.name,
        grasp=0,
        grasp_file=str(path),
        theta_deg=60.0,
        protocol_params=dict(TINY_PROTOCOL),
    )
    record = run_trial(spec, hand=shadow, obj=cube)
    outcome = outcome_of(record)
    assert outcome.held and not outcome.error
    assert record.arrays()["n_contacts"].min() >= 10  # fingers and palm, not only the tips


def _split_toy(folder: Path, floor_body: bool) -> Path:
    """The toy MJCF with its hand body moved to an ``<include>``d file, after a floor body
    (``floor_body``: a scene) or alone."""
    text = (folder / "toy.xml").read_text()
    start, end = text.index('<body name="palm"'), text.index("</worldbody>")
    (folder / "hand_body.xml").write_text(f"<mujoco>{text[start:end]}</mujoco>")
    floor = '<body name="floor_body"><site name="target"/></body>' if floor_body else ""
    (folder / "toy.xml").write_text(
        text[:start] + floor + '<include file="hand_body.xml"/>' + text[end:]
    )
    return folder


@pytest.mark.parametrize("floor_body", [False, True], ids=["include", "scene"])
def test_an_included_or_scene_file_gives_the_plain_files_kinematics(tmp_path, floor_body):
    rpy = (0.3, -0.5, 1.2)
    plain = load_hand(write_toy_hand(tmp_path / "plain", mjcf=True, palm_rpy=rpy))
    folder = _split_toy(write_toy_hand(tmp_path / "split", mjcf=True, palm_rpy=rpy), floor_body)
    if floor_body:
        with pytest.raises(ConfigError, match="2 root bodies \\['floor_body', 'palm'\\]"):
            load_hand(folder)
        toml = folder / "hand.toml"
        toml.write_text(toml.read_text().replace("palm_link", 'root_body = "palm"\npalm_link', 1))
    split = load_hand(folder)
    assert split.joint_names == plain.joint_names and split.link_names == plain.link_names
    q = plain.couple(np.array([0.3, 0.2, 0.6, 0.1, 0.4]))
    poses = []
    for hand in (plain, split):
        data = hand.model.createData()
        pin.framesForwardKinematics(hand.model, data, q)
        poses.append([data.oMf[int(f)].homogeneous for f in hand.link_frame])
    np.testing.assert_allclose(poses[0], poses[1], atol=1e-5)  # MuJoCo writes 6 digits
    MujocoBackend(split, ObjectModel.sphere(0.01, mass=0.01))  # the scene builds from it too


@pytest.mark.parametrize(
    ("top", "mjcf", "message"),
    [
        ('root_body = "nope"', True, "'nope' is not a root body of toy.xml; its root bodies are"),
        ('root_body = "palm"', False, "root_body names the hand's body in an MJCF scene file"),
        ("root_body = 3", True, "root_body names the hand's body"),
    ],
)
def test_a_bad_root_body_is_named(tmp_path, top, mjcf, message):
    folder = write_toy_hand(tmp_path / "toy", top=textwrap.dedent(top), mjcf=mjcf)
    with pytest.raises(ConfigError, match=message):
        load_hand(folder)
