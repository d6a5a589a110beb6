"""``wholehand bench soak``, short: every fault kind twice in a held grasp."""

from __future__ import annotations

import json

from wholehand.bench.soak import FAULTS
from wholehand.cli.main import main


def test_a_short_soak_meets_every_requirement(capsys):
    cycles, every = 2 * len(FAULTS) * 10 + 10, 10
    assert main(["bench", "soak", "--cycles", str(cycles), "--every", str(every)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["cycles"] == cycles and len(FAULTS) >= 20
    assert report["injected"] == dict.fromkeys(FAULTS, 2)
    assert report["exceptions"] == 0 and report["torque_limit_violations"] == 0
    assert report["recovered"] == report["n_injected"] == 2 * len(FAULTS)
    assert report["most_cycles_to_recover"] == 1 and report["held_at_end"] is True
    loop = report["loop"]
    assert loop["clamped"] == 2  # tau_over_limit, clamped before it is sent
    assert loop["stage_errors"] == 2 * 4  # estimator/allocator raising, NaN or short torques
    # Every observation fault is refused (pose_missing as no_pose): 12 kinds, twice.
    assert loop["faults"] == {"bad_state": 2 * 12, "stage_error": 2 * 4, "no_pose": 2}
    assert loop["status_counts"]["bad_contacts"] == 4  # zero or NaN normals only
    # Every cycle without a new torque kept the last one: the faults, the degenerate normals and
    # the failed solves; each alone, since every fault is recovered on the next cycle.
    counts = loop["status_counts"]
    kept = sum(loop["faults"].values()) + counts["bad_contacts"] + counts["solver_failed"]
    assert loop["held_commands"] == kept and loop["longest_hold"] == 1
    # A joint 40 rad past its limit is a broken reading, refused before the gate sees it.
    assert "joints" not in loop["gate_refused"] and loop["gate_refused"]["workspace"] == 2
