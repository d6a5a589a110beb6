"""What a running MuJoCo scene reports: the hand-object contacts with their forces (ground truth
for baselines and studies, never the controller's) and MuJoCo's warning counts (divergence)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt

from wholehand.backends.ground_truth import SimContacts

from .scene import HandObjectScene

if TYPE_CHECKING:
    pass

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


def hand_object_contacts(scene: HandObjectScene, data: mujoco.MjData) -> SimContacts:
    """The hand-object contacts of ``data`` with their forces (call after a step or mj_forward).

    MuJoCo's contact frame has its first axis (the normal) pointing from ``geom1`` to ``geom2``,
    and :func:`mujoco.mj_contactForce` gives, in that frame, the force ``geom1`` exerts on
    ``geom2``, with a positive (repulsive) normal component. So when the object is ``geom1`` the
    normal already points out of the object and the force on the object is the opposite of that
    force; when the object is ``geom2`` the normal is flipped and the force is taken as it is.
    Either way the force on the object has a negative component along the outward normal.
    """
    model = scene.model
    ncon = int(data.ncon)
    empty = SimContacts(
        p_world=np.zeros((0, 3)),
        n_world=np.zeros((0, 3)),
        f_world=np.zeros((0, 3)),
        link=np.zeros(0, dtype=np.intp),
        distance=np.zeros(0),
        geom_object=np.zeros(0, dtype=np.intp),
        stamp=float(data.time),
    )
    if ncon == 0:
        return empty
    contact = data.contact
    geoms = np.asarray(contact.geom, dtype=np.intp).reshape(ncon, 2)
    is_obj = scene.geom_is_object[geoms]
    keep = (is_obj[:, 0] ^ is_obj[:, 1]) & (np.asarray(contact.exclude).reshape(ncon) == 0)
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        return empty
    frames = np.asarray(contact.frame, dtype=float).reshape(ncon, 3, 3)[idx]
    # +1 where the object is geom2: force on it as given, normal (geom1 -> geom2) flipped.
    obj_is_geom2 = np.where(is_obj[idx, 1], 1.0, -1.0)
    n_world = -obj_is_geom2[:, None] * frames[:, 0, :]
    local = np.zeros((idx.size, 6))
    for k, c in enumerate(idx):
        mujoco.mj_contactForce(model, data, int(c), local[k])
    # frame rows are the contact axes (normal, tangent 1, tangent 2): world = frame^T @ local.
    f_world = obj_is_geom2[:, None] * np.einsum("kij,ki->kj", frames, local[:, :3])
    hand_geom = np.where(is_obj[idx, 0], geoms[idx, 1], geoms[idx, 0])
    obj_geom = np.where(is_obj[idx, 0], geoms[idx, 0], geoms[idx, 1])
    dist = np.asarray(contact.dist, dtype=float).reshape(ncon)[idx]
    pos = np.asarray(contact.pos, dtype=float).reshape(ncon, 3)[idx]
    link = scene.geom_link[hand_geom]
    valid = link >= 0
    return SimContacts(
        p_world=(pos + 0.5 * dist[:, None] * n_world)[valid],
        n_world=n_world[valid],
        f_world=f_world[valid],
        link=link[valid],
        distance=dist[valid],
        geom_object=obj_geom[valid],
        stamp=float(data.time),
    )


WARNINGS = {
    "inertia": mujoco.mjtWarning.mjWARN_INERTIA,
    "contact_full": mujoco.mjtWarning.mjWARN_CONTACTFULL,
    "constraint_full": mujoco.mjtWarning.mjWARN_CNSTRFULL,
    "bad_qpos": mujoco.mjtWarning.mjWARN_BADQPOS,
    "bad_qvel": mujoco.mjtWarning.mjWARN_BADQVEL,
    "bad_qacc": mujoco.mjtWarning.mjWARN_BADQACC,
    "bad_ctrl": mujoco.mjtWarning.mjWARN_BADCTRL,
}
"""MuJoCo's run-time warnings by short name."""


def warning_counts(data: mujoco.MjData) -> dict[str, int]:
    """How often each MuJoCo run-time warning fired since the last reset."""
    return {name: int(data.warning[int(w)].number) for name, w in WARNINGS.items()}
