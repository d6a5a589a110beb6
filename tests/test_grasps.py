"""Grasp files and the seeded grasp generator."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wholehand.errors import ConfigError
from wholehand.grasps.generate import generate_grasps
from wholehand.grasps.store import FORMAT, Grasp, load_grasps, save_grasps
from wholehand.models.objects import PAPER_OBJECTS, load_object


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_ten_power_grasps_ship_for_each_paper_object(allegro, name):
    grasps = load_grasps("allegro_right", name)
    assert len(grasps) >= 10
    for g in grasps:
        assert g.type == "power" and g.contacts >= 3
        q = g.q_array(allegro)
        # MuJoCo's joint limits are soft: pressed fingers sit a few mrad past them.
        assert np.all(q >= allegro.q_lower - 0.01) and np.all(q <= allegro.q_upper + 0.01)
        assert "thumb" in g.extra["fingers"] and len(g.extra["fingers"]) >= 3


def test_generation_is_deterministic_and_reproduces_the_shipped_grasps(allegro):
    cube = load_object("077_rubiks_cube")
    generated, info = generate_grasps(allegro, cube, count=2, seed=0)
    shipped = load_grasps("allegro_right", "077_rubiks_cube")[:2]
    assert info["seed"] == 0
    for g, s in zip(generated, shipped, strict=True):
        np.testing.assert_allclose(g.oMb, s.oMb, atol=1e-8)
        assert g.q == pytest.approx(s.q, abs=1e-8)
        assert g.contacts == s.contacts


def test_round_trip_and_bad_files(tmp_path, allegro):
    grasp = Grasp(0, np.eye(4), dict.fromkeys(allegro.joint_names, 0.1), contacts=4)
    path = save_grasps(tmp_path / "g.json", "allegro_right", "box", [grasp], {"seed": 1})
    (loaded,) = load_grasps(path)
    np.testing.assert_array_equal(loaded.oMb, np.eye(4))
    np.testing.assert_allclose(loaded.q_array(allegro), 0.1)

    raw = json.loads(path.read_text())
    raw["format"] = "other/1"
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match=FORMAT):
        load_grasps(path)
    raw["format"] = FORMAT
    raw["grasps"][0]["oMb"] = np.ones((4, 4)).tolist()
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match="oMb"):
        load_grasps(path)
    with pytest.raises(ConfigError, match="no grasp file.*shipped grasp files"):
        load_grasps("allegro_right", "no_object")
    partial = Grasp(0, np.eye(4), {"joint_0.0": 0.0})
    with pytest.raises(ConfigError, match="no angle for joints"):
        partial.q_array(allegro)
