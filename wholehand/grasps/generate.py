"""Grasps generated in MuJoCo (Dexonomy's grasps are not available offline).

A grasp style of hand.toml (:class:`~wholehand.models.hand_config.GraspStyle`) says how: ``power``
from ``[grasping]``, ``precision`` from ``[grasping.precision]``. For a hand and an object, each
seeded candidate:

1. turns the object to a random orientation and places it in front of the palm side of the palm
   link, at a gap drawn from the style's ``palm_gap`` [m]: for power grasps at a random offset
   along the palm; for a style that names its fingers, centred (+- 1 cm) across the palm on the
   mean of those fingers' distal links with the closing joints half-way to their limits;
2. opens the hand to the style's pre-shape; a candidate whose pre-shape already penetrates the
   object is rejected;
3. holds the object in place with a stiff spring-damper wrench and applies the style's closing
   torques (the other joints are held at the pre-shape by a PD law) until the required fingers
   touch the object (MuJoCo contacts): the thumb and two other fingers, or exactly the style's
   fingers; then ``CLOSE_EXTRA`` s more;
4. releases the object and lets the grasp settle for ``SETTLE`` s under the same torques; the
   grasp is kept if the required fingers still touch (and, for a style that names its fingers,
   no other link does: the palm stays free), the grasp-loss criterion holds and the object moved
   less than ``MAX_SETTLE_MOTION`` [m].

The hand base pose in the object frame and the joint angles after settling are stored.

On a table (``on_table``) the object instead rests on one of its stable faces
(:mod:`wholehand.models.resting`; the faces take turns,
:class:`~wholehand.grasps.face_schedule.FaceSchedule`) at a random yaw, and the hand comes from
above: the palm normal points down, tilted by up to ``MAX_TILT`` from
the vertical, turned at random about itself, with the object placed in front of the palm as in
step 1. The table is
there while the fingers close, so they cannot reach under the object, and is taken away for the
settling, so that only a grasp that holds the object by itself is kept. A candidate whose
pre-shape or settled grasp (with the object back on its face) comes within ``HAND_MARGIN`` of
the table top is rejected. The face's up direction is stored with the grasp (``table_up``).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from wholehand import registry
from wholehand.backends.table import HAND_MARGIN, Table
from wholehand.errors import ConfigError
from wholehand.grasps.checks import GraspCheck, passes
from wholehand.grasps.closing import Closing, ClosingStage
from wholehand.grasps.face_schedule import FaceSchedule
from wholehand.grasps.store import LIMIT_SLACK, Grasp, joint_past_limits
from wholehand.loop.control_loop import ControlLoop
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel
from wholehand.models.hand_config import GraspStyle
from wholehand.models.hand_folders import is_shipped_hand
from wholehand.models.kinematics import HandKinematics, lowest_point
from wholehand.models.objects import ObjectModel
from wholehand.models.palm import palm_frame
from wholehand.models.poses import inverse
from wholehand.models.resting import RestingFace, resting_faces, resting_pose, up_rotation

FloatArray = npt.NDArray[np.float64]

PRECISION_JITTER = 0.01
"""Half-range of the random offset of a precision candidate across the palm [m]."""
CONTROL_RATE = 200.0
"""Rate of the closing controller in sim time [Hz]."""
CLOSE_TIMEOUT = 1.5
"""Longest closing phase [s]."""
CLOSE_EXTRA = 0.2
"""Closing time after the thumb and two fingers first touch [s]."""
SETTLE = 0.3
"""Settling time after the object is released [s]."""
MAX_SETTLE_MOTION = 0.01
"""Largest object displacement accepted during settling [m]."""
HOLD_FREQUENCY = 20.0
"""Natural frequency of the critically damped spring that holds the object in place during
closing [Hz]; its gains scale with the object's mass and inertia."""
PRESHAPE_DEPTH = 0.001
"""Deepest a pre-shape may reach into the object before the candidate is rejected [m]."""
MAX_CANDIDATES = 400
"""Candidates tried per object before the generator gives up on finding ``count`` grasps."""
MAX_TILT = np.radians(60.0)
"""On a table: largest tilt of the palm normal from straight down [rad]."""
GENERATOR_TABLE = Table(top=0.0, centre=(0.0, 0.0), size=(0.8, 0.8))
"""The table of table-top generation; the object rests on it at the world origin."""
TABLE_CLEAR = GENERATOR_TABLE.top + HAND_MARGIN
"""Lowest height a table-top candidate's hand may reach [m]."""


def named_style(hand: HandModel, name: str) -> GraspStyle:
    """The grasp style ``name`` of the hand's hand.toml; an unknown name raises ConfigError
    naming the defined ones."""
    cfg = hand.config
    if name not in cfg.grasp_styles:
        raise ConfigError(
            f"{cfg.path}: no grasp style {name!r}; this hand defines "
            f"{sorted(cfg.grasp_styles)} (add a [grasping.{name}] table)"
        )
    return cfg.grasp_styles[name]


class GraspGenerator:
    """Seeded grasp generation for one hand, one object and one grasp style in MuJoCo."""

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        backend: str = "mujoco",
        style: str | GraspStyle = "power",
        on_table: bool = False,
    ) -> None:
        self.hand, self.obj, self.on_table = hand, obj, on_table
        cfg = hand.config
        self.style = style if isinstance(style, GraspStyle) else named_style(hand, style)
        style = self.style.name
        table = "[grasping]" if style == "power" else f"[grasping.{style}]"
        if not self.style.close_torque:
            raise ConfigError(
                f"{cfg.path}: {table} close_torque is empty; the pre-shape generator needs the "
                "closing torque of each flexion joint (add it to hand.toml), or use the "
                "optimiser, which needs none: `wholehand grasps generate --method optimize`"
            )
        if not self.style.fingers and cfg.thumb is None:
            raise ConfigError(
                f"{cfg.path}: a power grasp needs the thumb and two other fingers to touch, and "
                'this hand names no thumb; set thumb = "<a key of [fingers]>", or define a style '
                "that names the fingers that must touch ([grasping.precision] fingers = [...])"
            )
        self.q_pre, self.tau_close, self.closing = style_arrays(hand, self.style)
        scene: dict[str, object] = {"base": "mocap", "table": GENERATOR_TABLE} if on_table else {}
        self.backend = registry.load(
            "backends", backend, hand=hand, obj=obj, q_init=self.q_pre, **scene
        )
        self.faces: list[RestingFace] = resting_faces(obj) if on_table else []
        self.kin = HandKinematics(hand)
        self.loss = GraspLossCheck(hand, obj)
        self.thumb = cfg.thumb
        # Candidate poses are built along the palm's axes, then mounted with hand.wMb.
        self.palm = palm_frame(hand, self.q_pre, self.tau_close)
        self._finger_centre = (
            self._distal_centre(self.style.fingers) if self.style.fingers else None
        )
        self.candidates_tried = 0
        """Candidates tried by the last :meth:`generate`."""
        self.interrupted = False
        """The last :meth:`generate` was ended by Ctrl-C."""
        self.grasps_per_face: list[int] = []
        """On a table: grasps the last :meth:`generate` made on each of :attr:`faces`."""
        self.deepest: dict[str, float] = {}
        """Per link, the deepest penetration of a pre-shape rejected for it [m] (last
        :meth:`generate`)."""
        self.rejections: Counter[str] = Counter()
        """Why candidates of the last :meth:`generate` were rejected: reason -> count."""

    def _distal_centre(self, fingers: tuple[str, ...]) -> FloatArray:
        """(3,) mean origin of the fingers' distal links half-way closed, along the palm axes
        [m]: each closing joint half-way from the pre-shape to its limit in the closing
        direction."""
        hand, q = self.hand, self.q_pre.copy()
        for name, torque in self.style.close_torque.items():
            joint = hand.model.joints[hand.model.getJointId(name)]
            limit = hand.q_upper[joint.idx_q] if torque > 0 else hand.q_lower[joint.idx_q]
            q[joint.idx_q] = 0.5 * (q[joint.idx_q] + limit)
        self.kin.update(q, np.eye(4))
        links = [self.hand.config.fingers[f][-1] for f in fingers]
        centre = np.mean([self.kin.frame_pose(link)[:3, 3] for link in links], axis=0)
        return self.palm.to_palm(centre)

    def candidate_pose(self, rng: np.random.Generator) -> FloatArray:
        """(4, 4) a seeded object pose in front of the palm, in the world, the hand at
        ``hand.wMb``: a random orientation, placed by :meth:`place`."""
        R = Rotation.random(random_state=rng).as_matrix()
        return self.hand.wMb @ self.place(R, rng)

    def table_candidate(
        self, rng: np.random.Generator, face: RestingFace
    ) -> tuple[FloatArray, FloatArray]:
        """A seeded table-top candidate on ``face``: the object's world pose (4, 4) resting on
        :data:`GENERATOR_TABLE` and the hand base's (4, 4) above it (see the module
        docstring)."""
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        tilt, azimuth, spin = rng.uniform(0.0, MAX_TILT), *rng.uniform(0.0, 2.0 * np.pi, 2)
        down = np.array(
            [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)]
        )
        # Palm axes in the world: x (the palm normal, toward the object) along `down`.
        wRp = Rotation.from_rotvec(spin * down).as_matrix() @ up_rotation(down).T[:, [2, 0, 1]]
        wMo = resting_pose(self.obj, face.up, yaw, (0.0, 0.0), GENERATOR_TABLE.top)
        bMo = self.place(wRp.T @ wMo[:3, :3], rng)
        return wMo, wMo @ inverse(bMo)

    def place(self, R: FloatArray, rng: np.random.Generator) -> FloatArray:
        """(4, 4) object pose in the hand base frame for the object turned by ``R`` (3, 3) in
        the palm frame (:mod:`wholehand.models.palm`): its lowest point along the palm normal
        at the style's gap from the palm face; for power grasps its centre within 1 cm of the
        middle of the palm across and 0-4 cm below the top of the palm; for a style that names
        its fingers, centred (+- 1 cm) on their half-closed distal links."""
        verts = np.asarray(self.obj.mesh.vertices) @ R.T
        palm = self.palm
        x = palm.face - verts[:, 0].min() + rng.uniform(*self.style.palm_gap)
        centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
        if self._finger_centre is None:
            y = palm.centre[1] - centre[1] + rng.uniform(-0.01, 0.01)
            z = palm.top + rng.uniform(-0.04, 0.0) - centre[2]
        else:
            y, z = (
                self._finger_centre[1:]
                - centre[1:]
                + rng.uniform(-PRECISION_JITTER, PRECISION_JITTER, 2)
            )
        bMo = np.eye(4)
        bMo[:3, :3] = palm.bRp @ R
        bMo[:3, 3] = palm.bRp @ np.array([x, y, z])
        return bMo

    def _fingers_touching(self) -> set[str]:
        """Fingers touching the object; the palm and other unassigned links count as ``""``."""
        contacts = self.backend.ground_truth_contacts()
        return {self.hand.link_finger[i] for i in contacts.link}

    def grasped(self, touching: set[str]) -> bool:
        """Whether fingers ``touching`` ("" for other links) make the style's grasp: the
        thumb and two others, or exactly the style's fingers."""
        if self.style.fingers:
            return touching == set(self.style.fingers)
        fingers = touching - {""}
        return self.thumb in fingers and len(fingers - {self.thumb}) >= 2

    def _hold(self, wMo: FloatArray) -> None:
        """Hold the object at ``wMo`` with a stiff, critically damped spring."""
        omega = 2.0 * np.pi * HOLD_FREQUENCY
        m, i = self.obj.mass, float(np.linalg.eigvalsh(self.obj.inertia).min())
        self.backend.set_object_spring(
            wMo, (m * omega**2, i * omega**2), (2 * m * omega, 2 * i * omega)
        )

    def _run(
        self, duration: float, closing: Closing, until: Callable[[], bool] | None = None
    ) -> bool:
        """Run the closing stage for ``duration`` [s] or until ``until`` holds (checked every
        5 cycles and once when the time is up); True when it held (or there is no ``until``)."""
        stage = ClosingStage(*closing, until=until)
        ControlLoop(self.backend, self.hand, self.obj, stage, rate=CONTROL_RATE).run(duration)
        if until is None:
            return True
        return stage.closed or (stage.cycles % stage.check_every == 0 and until())

    def _reject(self, reason: str) -> Grasp | None:
        """Count a rejected candidate's reason; None, the rejected candidate's result."""
        self.rejections[reason] += 1
        return None

    def try_candidate(self, index: int, seed: int, face: RestingFace | None = None) -> Grasp | None:
        """One candidate (on a table, resting on ``face``, by default the likeliest); the
        grasp, or None when it is rejected (the reason is counted in :attr:`rejections`)."""
        rng = np.random.default_rng([seed, index])
        b = self.backend
        if self.on_table:
            face = face or self.faces[0]
            wMo, wMb = self.table_candidate(rng, face)
            b.reset(self.q_pre, wMo, wMb)
            b.set_table_contact(True)
            if lowest_point(self.hand, self.q_pre, wMb, self.kin) < TABLE_CLEAR:
                return self._reject("the pre-shape reaches into the table")
        else:
            wMo = self.candidate_pose(rng)
            b.reset(self.q_pre, wMo)
        contacts = b.ground_truth_contacts()
        if np.any(contacts.distance < -PRESHAPE_DEPTH):
            deepest = int(np.argmin(contacts.distance))
            link = self.hand.link_names[int(contacts.link[deepest])]
            depth = -float(contacts.distance[deepest])
            self.deepest[link] = max(self.deepest.get(link, 0.0), depth)
            return self._reject(f"the pre-shape penetrates the object (deepest: {link})")
        return self.close_and_settle(wMo, (self.q_pre, self.tau_close, self.closing), face, index)

    def close_and_settle(
        self,
        wMo: FloatArray,
        closing: Closing,
        face: RestingFace | None = None,
        index: int = -1,
    ) -> Grasp | None:
        """Steps 3-4 of the module docstring from the backend's current state (the object at
        ``wMo`` (4, 4), world): close with ``closing`` while the object is held, release,
        settle and check; the grasp, or None when it is rejected (the reason is counted in
        :attr:`rejections`). ``index`` is stored as the grasp's ``candidate``."""
        b = self.backend
        self._hold(wMo)
        if not self._run(CLOSE_TIMEOUT, closing, lambda: self.grasped(self._fingers_touching())):
            return self._reject(
                f"the required fingers did not all touch within {CLOSE_TIMEOUT:g} s of closing"
            )
        self._run(CLOSE_EXTRA, closing)
        before = b.observe().wMo
        b.set_object_spring(None)
        if self.on_table:
            b.set_table_contact(False)
        self._run(SETTLE, closing)
        state = b.observe()
        self.kin.update(state.q, state.wMb)
        moved = float(np.linalg.norm(state.wMo[:3, 3] - before[:3, 3]))
        touching = self._fingers_touching()
        fingers = touching - {""}
        if moved > MAX_SETTLE_MOTION:
            return self._reject(
                f"the object moved more than {1e3 * MAX_SETTLE_MOTION:g} mm when released"
            )
        if not self.grasped(touching):
            return self._reject("a required finger let go after release (or another link touched)")
        if not self.loss.held(self.kin, state.wMo):
            return self._reject("the grasp-loss criterion fails after release")
        oMb = inverse(state.wMo) @ state.wMb
        if face is not None:
            wMo_rest = resting_pose(self.obj, face.up, 0.0, (0.0, 0.0), GENERATOR_TABLE.top)
            if lowest_point(self.hand, state.q, wMo_rest @ oMb, self.kin) < TABLE_CLEAR:
                return self._reject(
                    f"the grasp comes within {1e3 * HAND_MARGIN:g} mm of the table top"
                )
        hand = self.hand
        if joint_past_limits(hand, state.q) is not None:
            return self._reject(
                f"a joint settled more than {LIMIT_SLACK:g} rad past its limit (MuJoCo's soft "
                "limits)"
            )
        q = {
            name: float(state.q[hand.model.joints[hand.model.getJointId(name)].idx_q])
            for name in hand.joint_names
        }
        return Grasp(
            id=-1,
            oMb=oMb,
            q=q,
            type=self.style.name,
            contacts=len(b.ground_truth_contacts()),
            extra={
                "candidate": index,
                "fingers": sorted(fingers),
                "settle_motion_m": round(moved, 6),
                **({} if face is None else {"table_up": np.round(face.up, 9).tolist()}),
            },
        )

    def generate(
        self,
        count: int = 10,
        seed: int = 0,
        max_candidates: int = MAX_CANDIDATES,
        progress: bool = False,
        check: GraspCheck | None = None,
    ) -> list[Grasp]:
        """Up to ``count`` grasps from at most ``max_candidates`` seeded candidates, in order;
        with ``check``, only the grasps that also pass it. Ctrl-C ends the search with the grasps
        found so far (:attr:`interrupted`)."""
        from tqdm import tqdm

        grasps: list[Grasp] = []
        bar = tqdm(total=count, desc=f"grasps {self.obj.name}", disable=not progress)
        self.candidates_tried = 0
        self.rejections.clear()
        self.deepest.clear()
        schedule = FaceSchedule(self.faces, count) if self.on_table else None
        self.grasps_per_face = schedule.found if schedule else []
        self.interrupted = False
        try:
            for index in range(max_candidates):
                self.candidates_tried = index + 1
                on = schedule.next() if schedule else 0
                grasp = self.try_candidate(index, seed, self.faces[on] if schedule else None)
                grasp = grasp and passes(grasp, check, self.rejections)
                if schedule:
                    schedule.record(on, 1, grasp is not None)
                if grasp is not None:
                    grasps.append(
                        Grasp(
                            len(grasps), grasp.oMb, grasp.q, grasp.type, grasp.contacts, grasp.extra
                        )
                    )
                    bar.update(1)
                    if len(grasps) == count:
                        break
        except KeyboardInterrupt:  # Ctrl-C: keep what was found
            self.interrupted = True
        bar.close()
        return grasps


def generate_command(
    method: str,
    hand: HandModel,
    obj: ObjectModel,
    count: int,
    seed: int,
    max_candidates: int,
    style: str,
    on_table: bool,
) -> str:
    """The ``wholehand grasps generate`` command line that makes these grasps again
    (``method`` "" for the default)."""
    command = "wholehand grasps generate" + (f" --method {method}" if method else "")
    folder = hand.config.path.parent
    command += f" --hand {hand.name if is_shipped_hand(folder) else folder}"
    command += f" --object {obj.name} --count {count} --seed {seed}"
    if max_candidates != MAX_CANDIDATES:
        command += f" --max-candidates {max_candidates}"
    if style != "power":
        command += f" --type {style}"
    return command + (" --on-table" if on_table else "")


def generate_grasps(
    hand: HandModel,
    obj: ObjectModel,
    count: int = 10,
    seed: int = 0,
    max_candidates: int = MAX_CANDIDATES,
    progress: bool = False,
    style: str = "power",
    on_table: bool = False,
    check: GraspCheck | None = None,
) -> tuple[list[Grasp], dict[str, object]]:
    """Grasps (with ``check``: only those that pass it) and a description of how they were
    made (for the file's ``generator`` field)."""
    started = time.perf_counter()
    generator = GraspGenerator(hand, obj, style=style, on_table=on_table)
    grasps = generator.generate(count, seed, max_candidates, progress, check)
    where = "resting on a table, hand from above, " if on_table else ""
    info = {
        "command": generate_command("", hand, obj, count, seed, max_candidates, style, on_table),
        "seed": seed,
        "method": f"{style} pre-shape, {where}closing torques with the object held, settle "
        "released (wholehand/grasps/generate.py)",
        "candidates_tried": generator.candidates_tried,
        **({"grasps_per_face": generator.grasps_per_face} if on_table else {}),
        **({"interrupted": True} if generator.interrupted else {}),
        "rejected": dict(generator.rejections.most_common()),
        "preshape_depth_mm": {
            link: round(1e3 * depth, 2) for link, depth in sorted(generator.deepest.items())
        },
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    return grasps, info
