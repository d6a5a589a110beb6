"""The paper's grasp-loss criterion (Sec. III-D).

The grasp is lost when the convex hull of the fingertips and the palm no longer intersects the
object's bounding box. Fingertips are represented by the centroid of each fingertip link's
surface samples, the palm by the eight corners of its samples' bounding box (both rigid in their
link frames); the object's bounding box is its mesh's axis-aligned box in the object frame.

The test is coal's GJK between the convex hull of those points and the box. GJK needs only the
hull's support function, the farthest point along a direction, and coal evaluates it by a linear
scan over all points for a convex of at most :data:`LINEAR_SUPPORT_MAX_POINTS` points. For such
hands the points are handed to coal as they are, without computing their hull (qhull per cycle
cost a large share of a simulated trial); with more points the hull is computed.

Most cycles need no GJK: a cheap test (:func:`clear_verdict`) settles the cases far from the
border, where GJK cannot disagree. The hull meets the box when a point of it (a hull point, the
fingertips' centroid, the centroid of all points) lies inside the box by :data:`CLEAR_MARGIN`;
it misses the box when every point lies beyond one face of the box by that margin. Only the
cases between go to coal.
"""

from __future__ import annotations

import coal
import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE
from wholehand.loop.control_loop import Cycle, Observer
from wholehand.loop.stage import LoopStatus
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]

CLEAR_MARGIN = 1e-4
"""Depth [m] inside or beyond the box at which :func:`clear_verdict` decides without GJK: a
hundred times coal's GJK tolerance (1e-6), so GJK's answer there is the same."""

LINEAR_SUPPORT_MAX_POINTS = 32
"""Largest convex coal supports by a scan over all its points (coal 3's
``ConvexBase::num_vertices_large_convex_threshold``); larger ones climb the hull's vertex graph,
which needs the true hull."""


class GraspLossCheck:
    """Decides, from the hand kinematics and the object pose, whether the object is still held."""

    def __init__(self, hand: HandModel, obj: ObjectModel) -> None:
        samples = hand.samples
        points, joints = [], []
        for i in np.flatnonzero(hand.link_fingertip):
            rows = samples.link == i
            points.append(samples.p_joint[rows].mean(axis=0))
            joints.append(int(hand.link_joint[i]))
        palm = hand.link_index(hand.palm_link)
        rows = samples.link == palm
        lo, hi = samples.p_joint[rows].min(axis=0), samples.p_joint[rows].max(axis=0)
        for corner in np.array(np.meshgrid(*zip(lo, hi, strict=True))).reshape(3, -1).T:
            points.append(corner)
            joints.append(int(hand.link_joint[palm]))
        self._p_joint = np.asarray(points)
        self._joint = np.asarray(joints, dtype=np.intp)
        self._n_tips = int(np.count_nonzero(hand.link_fingertip))
        lo, hi = obj.mesh.bounds
        self._half = 0.5 * (hi - lo)
        self._box = coal.Box(*(hi - lo))
        self._oMbox = np.eye(4)
        self._oMbox[:3, 3] = 0.5 * (lo + hi)
        self._request = coal.CollisionRequest()
        # Any face list will do for a convex whose support is a scan over its points.
        self._scan_only = len(self._p_joint) <= LINEAR_SUPPORT_MAX_POINTS
        self._faces = coal.StdVec_Triangle()
        self._faces.append(coal.Triangle(0, 1, 2))
        clear_verdict(self._p_joint, np.eye(4), self._half, self._n_tips, CLEAR_MARGIN)  # load it

    def hull_points(self, kinematics: HandKinematics) -> FloatArray:
        """(M, 3) world points whose convex hull stands for the grasping hand [m]."""
        return kinematics.transform_points(self._p_joint, self._joint)

    def held(self, kinematics: HandKinematics, wMo: FloatArray) -> bool:
        """True while the hull of fingertips and palm intersects the object's bounding box."""
        points = self.hull_points(kinematics)
        wMbox = wMo @ self._oMbox
        verdict = clear_verdict(points, wMbox, self._half, self._n_tips, CLEAR_MARGIN)
        if verdict >= 0:
            return bool(verdict)
        return self._gjk(points, wMbox)

    def _gjk(self, points: FloatArray, wMbox: FloatArray) -> bool:
        """coal's verdict: the hull of ``points`` (M, 3) [m] meets the box at ``wMbox``."""
        vertices = coal.StdVec_Vec3s()
        for p in points:
            vertices.append(p)
        if self._scan_only:
            hull = coal.Convex(vertices, self._faces)
        else:
            hull = coal.Convex.convexHull(vertices, False, "")
        tf_box = coal.Transform3s(wMbox[:3, :3].copy(), wMbox[:3, 3].copy())
        result = coal.CollisionResult()
        return bool(
            coal.collide(hull, coal.Transform3s(), self._box, tf_box, self._request, result)
        )


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def clear_verdict(  # noqa: C901 - one compiled pass over the points
    points: FloatArray, wMbox: FloatArray, half: FloatArray, n_tips: int, margin: float
) -> int:  # pragma: no cover - jit
    """1 when the hull of ``points`` (M, 3, world) [m] clearly meets the box of half sides
    ``half`` (3,) [m] at pose ``wMbox``, 0 when it clearly misses it, -1 when neither is clear
    (see the module docstring). The first ``n_tips`` points are the fingertips."""
    m = points.shape[0]
    local = np.empty((m, 3))
    for i in range(m):
        for a in range(3):
            local[i, a] = (
                wMbox[0, a] * (points[i, 0] - wMbox[0, 3])
                + wMbox[1, a] * (points[i, 1] - wMbox[1, 3])
                + wMbox[2, a] * (points[i, 2] - wMbox[2, 3])
            )
    for a in range(3):
        above = below = True
        for i in range(m):
            above = above and local[i, a] >= half[a] + margin
            below = below and local[i, a] <= -half[a] - margin
        if above or below:
            return 0
    # Points of the hull: each point, the fingertips' centroid, the centroid of all points.
    tips = np.zeros(3)
    every = np.zeros(3)
    for i in range(m):
        for a in range(3):
            every[a] += local[i, a] / m
            if i < n_tips:
                tips[a] += local[i, a] / n_tips
    for c in range(m + 2):
        inside = True
        for a in range(3):
            x = local[c, a] if c < m else tips[a] if c == m else every[a]
            inside = inside and abs(x) <= half[a] - margin
        if inside:
            return 1
    return -1


LOST = "grasp lost"
"""Reason a run stopped by :class:`GraspLossMonitor` gives."""


class GraspLossMonitor(Observer):
    """Applies :class:`GraspLossCheck` every cycle to the true object pose and the current q.

    Args:
        hand, obj: the models.
        stop_on_loss: end the run on the first cycle the grasp is lost.

    Attributes:
        held: the latest verdict (a cycle whose observation was unusable keeps the previous one).
        lost_at: backend time of the first cycle the grasp was lost [s] (None while held).
    """

    def __init__(self, hand: HandModel, obj: ObjectModel, stop_on_loss: bool = True) -> None:
        self.check = GraspLossCheck(hand, obj)
        self.stop_on_loss = stop_on_loss
        self.held = True
        self.lost_at: float | None = None

    def on_cycle(self, cycle: Cycle) -> str | None:
        if cycle.output.status != LoopStatus.BAD_STATE.value and cycle.truth.wMo is not None:
            self.held = self.check.held(cycle.context.kinematics, cycle.truth.wMo)
        if not self.held and self.lost_at is None:
            self.lost_at = cycle.t
        return LOST if not self.held and self.stop_on_loss else None
