"""The ``mink`` reacher's clearance limits on the hand's surface samples, and the wrapper that
holds a limit's violations instead of undoing them.

Both clearance limits constrain surface samples of the hand (:attr:`HandModel.samples`), one
row per sample, ``-dd/dq dq <= gain (d - clearance)`` with ``d`` the sample's distance to the
table top or to the object and ``dq`` the step's displacement (mink's QP variable, the velocity
times ``dt``): one step may close at most ``gain`` of the gap left above ``clearance``, and
a sample within the clearance must move out by ``gain`` of its violation. (mink's
``CollisionAvoidanceLimit`` divides that bound by ``dt`` as if the variable were the velocity:
200 times too loose above the clearance at 200 Hz, and within it a demand to move out by 170
times the violation in one step, which the other limits then seldom allow.) A sample is
constrained once it is within ``detection`` of the surface, the nearest ``per_link`` of each
link, so that the number of rows, and with it the step's time, has a bound that does not depend
on the object's shape.
"""

from __future__ import annotations

from typing import Protocol

import mink
import mujoco
import numpy as np
import numpy.typing as npt
from wholehand_plugins.mesh_sdf import MeshSDFEstimator

from wholehand.backends.table import Table
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]


class ReachState(Protocol):
    """What a limit reads of the reacher: its models and its current state."""

    hand: HandModel
    model: mujoco.MjModel

    def hand_kinematics(self) -> HandKinematics:
        """The hand's kinematics at the IK model's current joint angles and base pose."""
        ...

    def object_pose(self) -> FloatArray:
        """(4, 4) the object's pose in the IK model [m]."""
        ...


def _link_bodies(state: ReachState) -> npt.NDArray[np.intp]:
    """The IK model's body of each hand link (index of ``hand.link_names``)."""
    return np.array([state.model.body(name).id for name in state.hand.link_names], dtype=np.intp)


def _hull_samples(rows: npt.NDArray[np.intp], p_joint: FloatArray) -> npt.NDArray[np.intp]:
    """Those of the samples ``rows`` (one link's, in its joint's frame) that are vertices of
    their convex hull; all of them where the hull is degenerate (fewer than 4, or flat)."""
    from scipy.spatial import ConvexHull, QhullError

    if rows.size < 4:
        return rows
    try:
        return rows[np.sort(ConvexHull(p_joint[rows]).vertices)]
    except QhullError:
        return rows


class TableLimit(mink.Limit):
    """Keeps the hand's surface samples above the table top (a half-space), point by point.

    mink's ``CollisionAvoidanceLimit`` constrains one witness point per geom pair; when a box
    face comes down parallel to the table that point is arbitrary on the face, and a small
    rotation about it lowers another corner unconstrained (measured: a palm box 7.5 mm into the
    table). Here every sample within ``detection`` of the plane gets its own row, the lowest
    ``per_link`` of each link among the vertices of the convex hull of its samples: a rigid
    link's lowest point is one of them, so that a face coming down flat is held at its
    corners, not at the few samples that happen to be lowest (a turn about those lowers the
    rest). Only the links whose bounding sphere (about their joint's origin)
    comes that near the plane have their samples transformed: away from the table the limit
    costs one pass of forward kinematics.
    """

    def __init__(
        self,
        state: ReachState,
        table: Table,
        gain: float,
        clearance: float,
        detection: float,
        per_link: int = 8,
    ) -> None:
        self.state, self.table = state, table
        self.gain, self.clearance, self.detection = gain, clearance, detection
        self.per_link = per_link
        self._body = _link_bodies(state)
        self._jac = np.zeros((3, state.model.nv))
        samples = state.hand.samples
        self._rows = [
            _hull_samples(np.flatnonzero(samples.link == i), samples.p_joint)
            for i in range(len(self._body))
        ]
        self._joint = np.asarray(state.hand.link_joint, dtype=np.intp)
        self._radius = np.array(
            [
                np.linalg.norm(samples.p_joint[r], axis=1).max() if r.size else 0.0
                for r in self._rows
            ]
        )

    def compute_qp_inequalities(
        self, configuration: mink.Configuration, dt: float
    ) -> mink.limits.Constraint:
        top = self.table.top
        kin = self.state.hand_kinematics()
        samples = self.state.hand.samples
        reach = top + self.clearance + self.detection
        origins = kin.transform_points(np.zeros((len(self._joint), 3)), self._joint)
        links = np.flatnonzero(origins[:, 2] - self._radius < reach)
        if links.size == 0:
            return mink.limits.Constraint()
        candidates = np.concatenate([self._rows[i] for i in links])
        points = np.zeros((len(samples.link), 3))
        points[candidates] = kin.transform_points(
            samples.p_joint[candidates], samples.joint[candidates]
        )
        near = candidates[points[candidates, 2] < reach]
        if near.size == 0:
            return mink.limits.Constraint()
        rows = []
        for link in np.unique(samples.link[near]):
            mine = near[samples.link[near] == link]
            rows.extend(mine[np.argsort(points[mine, 2])[: self.per_link]].tolist())
        G = np.empty((len(rows), configuration.model.nv))
        h = np.empty(len(rows))
        for k, i in enumerate(rows):
            body = int(self._body[samples.link[i]])
            mujoco.mj_jac(configuration.model, configuration.data, self._jac, None, points[i], body)
            G[k] = -self._jac[2]
            h[k] = self.gain * (points[i, 2] - top - self.clearance)
        return mink.limits.Constraint(G=G, h=h)


class ObjectClearanceLimit(mink.Limit):
    """Keeps the hand's surface samples ``clearance`` off the object's surface, from its SDF.

    The samples within ``detection`` of the surface, the nearest ``per_link`` of each link, are
    found as the contact estimator finds contacts (:class:`MeshSDFEstimator`, with
    ``detection`` as its threshold: one compiled pass, culled by clusters); each gets a row
    along the SDF's gradient there, the object's outward normal. The distance is to the
    object's own surface, cavities included, and at most ``per_link`` rows per link are
    built whatever the object's shape; geom-pair distances to the parts of a convex
    decomposition cost one narrow-phase query per pair within reach (up to 576 pairs and 255
    rows on a Duplo brick with the HX5-D20, 1.5-1.8 ms a step on the development machine).
    """

    def __init__(
        self,
        state: ReachState,
        obj: ObjectModel,
        gain: float,
        clearance: float,
        detection: float,
        per_link: int = 3,
    ) -> None:
        self.state = state
        self.gain, self.clearance = gain, clearance
        try:
            self.nearest = MeshSDFEstimator(
                state.hand, obj, d_thresh=detection, k=per_link, hysteresis=0.0
            )
        except ConfigError as err:
            raise ConfigError(
                f"mink reacher: its object clearance looks {detection} m (detection) out from "
                f"{obj.name!r}, past the object's SDF grid ({err}); build the object with "
                f"sdf_padding above {detection} m or give the reacher a smaller detection"
            ) from None
        self._body = _link_bodies(state)
        self._jac = np.zeros((3, state.model.nv))

    def compute_qp_inequalities(
        self, configuration: mink.Configuration, dt: float
    ) -> mink.limits.Constraint:
        near = self.nearest.estimate(self.state.hand_kinematics(), self.state.object_pose())
        if len(near) == 0:
            return mink.limits.Constraint()
        G = np.empty((len(near), configuration.model.nv))
        for k in range(len(near)):
            body = int(self._body[near.link[k]])
            p = near.p_world[k]
            mujoco.mj_jac(configuration.model, configuration.data, self._jac, None, p, body)
            G[k] = -(near.n_world[k] @ self._jac)
        h = self.gain * (near.distance - self.clearance)
        return mink.limits.Constraint(G=G, h=h)


class HeldViolations(mink.Limit):
    """A limit whose violated rows (``h < 0``: the step must undo a violation) only keep the
    violation from growing (``h = 0``): with every limit so wrapped, standing still is a
    solution."""

    def __init__(self, limit: mink.Limit) -> None:
        self.limit = limit

    def compute_qp_inequalities(
        self, configuration: mink.Configuration, dt: float
    ) -> mink.limits.Constraint:
        G, h = self.limit.compute_qp_inequalities(configuration, dt)
        if G is None or h is None:
            return mink.limits.Constraint(G, h)
        return mink.limits.Constraint(G=G, h=np.maximum(h, 0.0))
