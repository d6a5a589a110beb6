"""Every Python block of the docs pages runs as written, on the names the page's text gives it
(a hand, an object, a backend at a held grasp, one cycle's state, a run's record). The README's
block has its own test (tests/test_readme.py); docs/adding_a_hand.md's commands have theirs
(tests/test_docs.py)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from wholehand import registry
from wholehand.grasps.store import load_grasps
from wholehand.models.hand import load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.trials.trial import TrialSpec, run_trial

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = sorted(p.name for p in DOCS.glob("*.md") if "```python" in p.read_text())


def _blocks(page: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (DOCS / page).read_text(), re.S)


@pytest.fixture(scope="module")
def names() -> dict[str, Any]:
    """What the pages' text assumes: the Allegro at the cube's stored grasp 0 in MuJoCo, and a
    short run's record and last state."""
    hand, obj = load_hand("allegro_right"), load_object("077_rubiks_cube")
    grasp = load_grasps(hand.name, obj.name)[0]
    backend = registry.load(
        "backends",
        "mujoco",
        hand=hand,
        obj=obj,
        q_init=grasp.q_array(hand),
        wMo_init=grasp.object_pose(hand.wMb),
    )
    record = run_trial(TrialSpec(theta_deg=0.0, protocol_params={"load_duration": 0.05}))
    obs = backend.observe()
    return {
        "hand": hand,
        "obj": obj,
        "backend": backend,
        "record": record,
        "q": obs.q,
        "wMo": obs.wMo,
        "wMb": obs.wMb,
        "contact_p": np.zeros((0, 3)),
        "contact_f": np.zeros((0, 3)),
    }


def test_the_pages_with_python_are_the_known_ones():
    assert PAGES == ["control_loop.md", "plugins.md", "visualisation.md"]


@pytest.mark.parametrize("page", PAGES)
def test_every_python_block_of_a_page_runs(page, names, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scope = dict(names)
    for i, block in enumerate(_blocks(page)):
        exec(compile(block, f"{page} block {i}", "exec"), scope)
    if page == "control_loop.md":  # the loop ran its 5 s at 200 Hz and nothing raised
        assert scope["report"].cycles == 1000 and scope["report"].n_errors == 0
    if page == "plugins.md":  # the example estimator works as the page says
        estimator = scope["AcmeEstimator"](hand=names["hand"], obj=names["obj"])
        from wholehand.models.kinematics import HandKinematics

        contacts = estimator.estimate(HandKinematics(names["hand"]), names["wMo"])
        assert len(contacts) == 0
    if page == "visualisation.md":
        assert (tmp_path / "run.html").stat().st_size > 1000
        assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"
