"""DexGraspBench's load test as a protocol (``TrialSpec(protocol="dexgraspbench")``).

The grasp-synthesis community scores grasps with the simulated load test of DexGraspBench
(Chen et al., github:JYChen18/DexGraspBench: ``src/task/eval_func/fc_mocap.py``,
``src/util/hand_util.py``, ``config/task/eval.yaml``). Re-implemented here from that definition
(no code taken; the repository has no licence), so that numbers of this library's methods can be
read next to those of grasp synthesis:

- gravity off; the object's mass set to 0.1 kg (inertia scaled with it); friction 0.6;
  contacts with torsional friction (``condim`` 4), elliptic cones, ``impratio`` 10;
- six directions, +-x, +-y, +-z of the world, each from the same initial state: the grasp
  closes, then a force of ``10 m/s^2 * m`` (1 N) pushes the object's centre of mass for 2 s;
- a direction fails once the object's frame has moved 5 cm or turned 15 deg from its pose at
  the start; the grasp passes if no direction fails (like DexGraspBench, the test stops at the
  first failed direction).

What differs, and why: DexGraspBench drives the hand with position targets (pre-grasp, grasp,
then a squeeze pose past the grasp); here each method's own law holds the stored grasp, after a
settle of :data:`SETTLE_TIME` in place of their closing motion. The pose is checked every
control cycle (theirs: every 0.2 s). Their torsional friction is 0.02, ours 0.005
(:mod:`wholehand_plugins.mujoco.object_spec`); their time step 4 ms, ours 1 ms (the Allegro's light
links need it).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.backends.base import PushesObject, ReportsWarnings
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.trials.protocol import DIRECTIONS, object_pusher

FloatArray = npt.NDArray[np.float64]

NAME = "dexgraspbench"
"""Value of ``TrialSpec.protocol`` that selects this protocol."""
MASS = 0.1
"""Object mass of the test [kg] (``obj_mass``)."""
FRICTION = 0.6
"""Sliding friction of hand-object contacts [-] (``miu_coef[0]``)."""
ACCELERATION = 10.0
"""The push is this acceleration times the mass [m/s^2]: 1 N."""
PUSH_TIME = 2.0
"""Duration of the push per direction [s]."""
MAX_TRANSLATION = 0.05
"""A direction fails once the object frame's origin moved this far [m] (``trans_thre``)."""
MAX_ROTATION_DEG = 15.0
"""... or the object turned this far [deg] (``angle_thre``)."""
SETTLE_TIME = 0.5
"""The method holds the grasp this long before each push [s]."""
BACKEND_OPTIONS: dict[str, Any] = {"condim": 4, "cone": "elliptic", "impratio": 10.0}
"""MuJoCo options of the test (the friction is the object's, :func:`bench_object`)."""


def bench_object(obj: ObjectModel) -> ObjectModel:
    """``obj`` with the test's mass (inertia scaled with it) and friction."""
    scale = MASS / obj.mass
    return dataclasses.replace(
        obj, mass=MASS, inertia=np.asarray(obj.inertia) * scale, friction=FRICTION
    )


def pose_change(wMo_start: FloatArray, wMo: FloatArray) -> tuple[float, float]:
    """How far the object frame moved [m] and turned [deg] from ``wMo_start`` to ``wMo``."""
    moved = float(np.linalg.norm(wMo[:3, 3] - wMo_start[:3, 3]))
    turned = float(np.linalg.norm(pin.log3(wMo_start[:3, :3].T @ wMo[:3, :3])))
    return moved, float(np.degrees(turned))


@dataclass
class DirectionResult:
    """The outcome of one direction."""

    direction: str
    passed: bool
    translation: float
    """Largest translation of the object frame during the run [m]."""
    rotation_deg: float
    """Largest rotation of the object during the run [deg]."""
    stopped_at: float
    """Time from the start of the run when it ended [s]."""
    failed_in: str = ""
    """``"settle"`` (the object moved too far while the method closed the grasp, before any
    push), ``"push"``, or "" if it passed."""


class Push(Observer):
    """After ``settle`` [s], pushes the object's centre of mass with ``force`` (3,) [N, world];
    ends the run once the object moved :data:`MAX_TRANSLATION` or turned
    :data:`MAX_ROTATION_DEG` from its pose at the start."""

    def __init__(self, force: FloatArray, settle: float) -> None:
        self.force, self.settle = np.asarray(force, dtype=float), settle
        self._backend: PushesObject | None = None
        self._t0 = 0.0
        self._start = np.eye(4)
        self.translation = self.rotation_deg = 0.0
        self.failed_in = ""
        """Where the run failed: "settle", "push", or "" while it has not."""
        self.elapsed = 0.0

    def on_start(self, loop: ControlLoop) -> None:
        self._backend = object_pusher(loop, NAME)
        self._t0 = loop.backend.time
        self._half_dt = 0.5 * loop.dt
        wMo = loop.backend.observe().wMo
        assert wMo is not None
        self._start = wMo.copy()

    def on_cycle(self, cycle: Cycle) -> str | None:
        assert self._backend is not None and cycle.truth.wMo is not None
        self.elapsed = cycle.t - self._t0
        moved, turned = pose_change(self._start, cycle.truth.wMo)
        self.translation = max(self.translation, moved)
        self.rotation_deg = max(self.rotation_deg, turned)
        pushing = self.elapsed + self._half_dt >= self.settle
        if moved >= MAX_TRANSLATION or turned >= MAX_ROTATION_DEG:
            self.failed_in = "push" if pushing else "settle"
            return f"object moved {1000 * moved:.0f} mm / turned {turned:.1f} deg"
        self._backend.apply_object_wrench(self.force if pushing else np.zeros(3), np.zeros(3))
        return None

    def on_end(self, loop: ControlLoop) -> None:
        if self._backend is not None:
            self._backend.apply_object_wrench(np.zeros(3), np.zeros(3))


def run_load_test(
    spec: Any,
    hand: HandModel,
    obj: ObjectModel,
    observers: Sequence[Observer] = (),
) -> dict[str, Any]:
    """DexGraspBench's load test of ``spec``'s grasp and method (a
    :class:`~wholehand.trials.trial.TrialSpec`; its ``theta_deg`` is not used): the six
    directions in order, each from a fresh scene at the stored grasp, until one fails.

    Returns ``held`` (every direction passed), ``directions`` (a :class:`DirectionResult` per
    direction run), ``failed_direction`` and ``failed_in`` ("" if none), the largest
    ``translation_m`` and ``rotation_deg`` over the directions run, ``sim_warnings`` (summed)
    and ``wall_time_s``.
    """
    from wholehand.trials.trial import set_up_trial

    if spec.gravity:
        raise ConfigError(f"the {NAME} protocol runs with gravity off; drop gravity=True")
    started = time.perf_counter()
    bench_obj = bench_object(obj)
    spec = dataclasses.replace(spec, backend_params={**BACKEND_OPTIONS, **spec.backend_params})
    results: list[DirectionResult] = []
    warnings: dict[str, int] = {}
    for name, direction in DIRECTIONS.items():
        trial = set_up_trial(spec, hand, bench_obj)
        push = Push(ACCELERATION * MASS * np.asarray(direction), SETTLE_TIME)
        loop = trial.loop([push, *observers], spec.control_rate)
        loop.run(SETTLE_TIME + PUSH_TIME)
        if isinstance(trial.backend, ReportsWarnings):
            for key, count in trial.backend.warnings().items():
                warnings[key] = warnings.get(key, 0) + int(count)
        results.append(
            DirectionResult(
                name,
                not push.failed_in,
                push.translation,
                push.rotation_deg,
                push.elapsed,
                push.failed_in,
            )
        )
        if push.failed_in:
            break
    failed = next((r for r in results if not r.passed), None)
    return {
        "held": failed is None,
        "directions": results,
        "failed_direction": "" if failed is None else failed.direction,
        "failed_in": "" if failed is None else failed.failed_in,
        "translation_m": max(r.translation for r in results),
        "rotation_deg": max(r.rotation_deg for r in results),
        "sim_warnings": warnings,
        "wall_time_s": time.perf_counter() - started,
    }
