"""The hand model: Pinocchio kinematics, coal geometry, link table and surface samples.

Links are the URDF links that carry geometry of the sampled surface kind. Surface samples are
stored in the frame of each link's parent joint, so one forward-kinematics pass (joint
placements) is all a cycle needs to move every sample.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh

from wholehand import defaults
from wholehand.errors import AssetError, ConfigError
from wholehand.models.coupling import (
    Mimic,
    coupling_matrix,
    mjcf_mimics,
    resolve_chains,
    urdf_mimics,
)
from wholehand.models.hand_config import HandConfig, parse_hand_config
from wholehand.models.hand_folders import resolve_hand_config
from wholehand.models.hand_samples import load_or_sample
from wholehand.models.mesh_files import check_meshes
from wholehand.models.mjcf_file import mjcf_for_parsers
from wholehand.models.poses import pose_from_xyz_rpy
from wholehand.models.surface import link_mesh_in_joint_frame
from wholehand.models.urdf_check import urdf_problems

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

SUPPORTED_JOINTS = {
    "JointModelRX",
    "JointModelRY",
    "JointModelRZ",
    "JointModelRevoluteUnaligned",
    "JointModelPX",
    "JointModelPY",
    "JointModelPZ",
    "JointModelPrismaticUnaligned",
}
"""Pinocchio joint types a hand may have: revolute and prismatic, one DoF each (nq = nv)."""


class HandModel:
    """A hand loaded from a hand.toml: kinematics, geometry, links, limits and samples.

    Attributes:
        config: the parsed hand.toml.
        model: Pinocchio model with a fixed base at the root link (the hand base frame ``b``).
        collision_model, visual_model: Pinocchio geometry models (coal geometry).
        link_names: (L,) names of the links that carry geometry, in link-index order.
        link_frame: (L,) Pinocchio frame id of each link.
        link_joint: (L,) Pinocchio joint id of each link's parent joint (0 for the base).
        link_actuated: (L,) True where forces are produced by actuated joints.
        link_fingertip: (L,) True for the distal links named in hand.toml.
        link_finger: (L,) finger name of each link ("" for links on no finger).
        actuated_dofs: (n_v,) True for torque-controlled velocity dimensions.
        tau_max: (n_v,) torque limits [N*m]: hand motors (``actuated_dofs``) and an assembly's
            arm joints (``arm_dofs``, the URDF's effort limits); 0 elsewhere.
        wMb: (4, 4) mount pose of the hand base in the world.
        samples: the surface samples (see :class:`SurfaceSamples`).
    """

    def __init__(
        self,
        config: HandConfig,
        n_uniform: int = defaults.UNIFORM_SAMPLES_PER_LINK,
        density_per_cm2: float = defaults.SAMPLE_DENSITY_PER_CM2,
        seed: int = 0,
    ) -> None:
        self.config = config
        self.parsed_model_path = (
            mjcf_for_parsers(config) if config.model_format == "mjcf" else config.model_path
        )
        """The model file Pinocchio and the MuJoCo scene read: ``config.model_path``, or an
        MJCF's self-contained copy (:mod:`wholehand.models.mjcf_file`), made once here."""
        full = self._build_model()
        self._check_joint_types(full)
        collision = self._build_geometry(full, pin.GeometryType.COLLISION, "collision")
        visual = self._build_geometry(full, pin.GeometryType.VISUAL, "visual")
        self.model, self.collision_model, self.visual_model = self._lock_joints(
            full, collision, visual
        )
        self._build_link_table()
        self._build_joint_tables()
        self.wMb = pose_from_xyz_rpy(config.mount_xyz, config.mount_rpy)
        self.sample_params: dict[str, Any] = {
            "n_uniform": int(n_uniform),
            "density_per_cm2": float(density_per_cm2),
            "seed": int(seed),
            "surface": config.sample_surface,
        }
        self.samples, self.samples_from_cache = load_or_sample(self)

    # --- construction -------------------------------------------------------------------------
    def _build_model(self) -> pin.Model:
        cfg = self.config
        mjcf = cfg.model_format == "mjcf"
        try:
            if mjcf:
                return pin.buildModelFromMJCF(str(self.parsed_model_path))
            return pin.buildModelFromUrdf(str(cfg.model_path))
        except Exception as err:
            problems = [] if mjcf else urdf_problems(cfg.model_path)
            if problems:
                raise AssetError(
                    f"{cfg.model_path}: Pinocchio cannot parse this URDF: " + "; ".join(problems)
                ) from err
            raise AssetError(
                f"{cfg.model_path}: Pinocchio cannot parse this {cfg.model_format.upper()} "
                f"({err}); check that it is well-formed XML"
                + (" that MuJoCo loads" if mjcf else " with one root link")
            ) from err

    def _check_joint_types(self, model: pin.Model) -> None:
        for jid in range(1, model.njoints):
            kind = model.joints[jid].shortname()
            if kind not in SUPPORTED_JOINTS:
                raise ConfigError(
                    f"{self.config.model_path}: joint {model.names[jid]!r} has type {kind}, "
                    "which a hand model does not support; use revolute (with limits) or "
                    "prismatic joints, and fixed joints for rigid attachments"
                )

    def _build_geometry(
        self, model: pin.Model, kind: pin.GeometryType, surface: str
    ) -> pin.GeometryModel:
        cfg = self.config
        if cfg.model_format == "urdf":
            check_meshes(cfg.model_path, cfg.package_dirs, surface)
        try:
            if cfg.model_format == "mjcf":  # collision: geoms with contype or conaffinity set
                geometry = pin.buildGeomFromMJCF(model, str(self.parsed_model_path), kind)
                for obj in list(geometry.geometryObjects):  # the world's own (a floor)
                    if model.frames[obj.parentFrame].type != pin.FrameType.BODY:
                        geometry.removeGeometryObject(obj.name)
                return geometry
            return pin.buildGeomFromUrdf(
                model,
                str(cfg.model_path),
                kind,
                package_dirs=[str(d) for d in cfg.package_dirs],
            )
        except Exception as err:
            raise AssetError(
                f"{cfg.model_path}: cannot build the {surface} geometry: {err}"
            ) from err

    def _lock_joints(
        self, model: pin.Model, collision: pin.GeometryModel, visual: pin.GeometryModel
    ) -> tuple[pin.Model, pin.GeometryModel, pin.GeometryModel]:
        """The model with the locked joints of hand.toml turned into fixed joints at their
        values (Pinocchio's reduced model), and its geometry."""
        cfg = self.config
        if not cfg.locked_joints:
            return model, collision, visual
        moving = [model.names[j] for j in range(1, model.njoints)]
        q_ref = pin.neutral(model)
        ids = []
        for name, value in cfg.locked_joints.items():
            if name not in moving:
                raise ConfigError(
                    f"{cfg.path}: locked joint {name!r} is not a moving joint of "
                    f"{cfg.model_path.name}; valid joints: {moving}"
                )
            jid = model.getJointId(name)
            i = model.joints[jid].idx_q
            low, high = model.lowerPositionLimit[i], model.upperPositionLimit[i]
            if not low <= value <= high:
                raise ConfigError(
                    f"{cfg.path}: [joints] locked.{name} = {value} is outside the joint's "
                    f"limits [{low:g}, {high:g}] in {cfg.model_path.name}"
                )
            q_ref[i] = value
            ids.append(jid)
        reduced, (coll, vis) = pin.buildReducedModel(model, [collision, visual], ids, q_ref)
        return reduced, coll, vis

    def _frame_id(self, link: str, what: str) -> int:
        if not self.model.existFrame(link, pin.FrameType.BODY):
            raise ConfigError(
                f"{self.config.path}: {what} {link!r} is not a link of "
                f"{self.config.model_path.name}; "
                f"valid links: {self.all_link_names}"
            )
        return int(self.model.getFrameId(link, pin.FrameType.BODY))

    @property
    def all_link_names(self) -> list[str]:
        """Every link of the URDF (Pinocchio BODY frames)."""
        return [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]

    def _build_link_table(self) -> None:
        cfg = self.config
        sampled = self.collision_model if cfg.sample_surface == "collision" else self.visual_model
        for link in cfg.excluded_links:
            self._frame_id(link, "excluded link")
        by_frame: dict[int, list[pin.GeometryObject]] = {}
        for obj in sampled.geometryObjects:
            if self.model.frames[obj.parentFrame].name not in cfg.excluded_links:
                by_frame.setdefault(obj.parentFrame, []).append(obj)
        self._link_geometry = by_frame
        frames = sorted(by_frame)
        self.link_names = [self.model.frames[f].name for f in frames]
        self.link_frame = np.array(frames, dtype=np.intp)
        self.link_joint = np.array(
            [self.model.frames[f].parentJoint for f in frames], dtype=np.intp
        )

        self.palm_link = cfg.palm_link
        named = [(cfg.palm_link, "palm_link")]
        named += [(n, "passive link") for n in cfg.passive_links]
        named += [(n, "fingertip link") for n in cfg.fingertip_links]
        named += [(n, f"link of finger {f!r}") for f, links in cfg.fingers.items() for n in links]
        for link, what in named:
            self._frame_id(link, what)
            if link in cfg.excluded_links:
                raise ConfigError(
                    f"{cfg.path}: {what} {link!r} is also in excluded_links; a link cannot be "
                    "both a contact link and excluded"
                )
            if link not in self.link_names:
                raise ConfigError(
                    f"{cfg.path}: {what} {link!r} has no {cfg.sample_surface} geometry in "
                    f"{cfg.model_path.name}, so it can never touch the object; links with "
                    f"geometry: {self.link_names}"
                )
        self.link_fingertip = np.array([n in cfg.fingertip_links for n in self.link_names])
        finger_of = {link: f for f, links in cfg.fingers.items() for link in links}
        self.link_finger = [finger_of.get(n, "") for n in self.link_names]

    def _couplings(self, moving: list[str]) -> dict[str, Mimic]:
        """The couplings among the model's joints, chains resolved: the model file's (URDF
        ``<mimic>``, MJCF joint equalities) and hand.toml's ``[joints] coupled``."""
        cfg = self.config
        mimics = (mjcf_mimics if cfg.model_format == "mjcf" else urdf_mimics)(cfg.model_path)
        for follower, m in cfg.coupled_joints.items():
            for name in (follower, m.leader):
                if name not in moving and name not in cfg.locked_joints:
                    raise ConfigError(
                        f"{cfg.path}: [joints] coupled.{follower}: {name!r} is not a moving joint "
                        f"of {cfg.model_path.name}; valid joints: {moving}"
                    )
            if follower in mimics:
                raise ConfigError(
                    f"{cfg.path}: joint {follower!r} is already coupled in "
                    f"{cfg.model_path.name} (to {mimics[follower].leader!r}); remove it from "
                    "[joints] coupled"
                )
            mimics[follower] = m
        locked = cfg.locked_joints
        for follower, m in list(mimics.items()):
            if (follower in locked) != (m.leader in locked):
                raise ConfigError(
                    f"{cfg.path}: joint {follower!r} mimics {m.leader!r} and only one of them is "
                    "locked; lock both ([joints] locked) or neither"
                )
            if follower in locked:
                del mimics[follower]
        tag = "<mimic>" if cfg.model_format == "urdf" else "<equality><joint>"
        sources = {
            follower: f"[joints] coupled in {cfg.path.name}"
            if follower in cfg.coupled_joints
            else f"{tag} in {cfg.model_path.name}"
            for follower in mimics
        }
        return resolve_chains(mimics, moving, cfg.model_path, sources)

    def _check_named_joints(self, actuated: list[str], moving: list[str]) -> None:
        """Raise :class:`ConfigError` for a joint that hand.toml actuates, limits or closes
        but that is locked, not a moving joint of the model, or a coupling's follower."""
        cfg = self.config
        styles = cfg.grasp_styles.values()
        grasp_joints = [j for st in styles for j in (*st.preshape, *st.close_torque)]
        for name in [*actuated, *cfg.torque_limits, *grasp_joints]:
            if name in cfg.locked_joints:
                raise ConfigError(
                    f"{cfg.path}: joint {name!r} is locked ([joints] locked), so it cannot be "
                    "actuated, have a torque limit or take part in a grasp style; remove it there"
                )
            if name not in moving:
                raise ConfigError(
                    f"{cfg.path}: joint {name!r} is not a moving joint of "
                    f"{cfg.model_path.name}; valid joints: {moving}"
                )
        motored = [*actuated, *cfg.torque_limits, *(j for st in styles for j in st.close_torque)]
        in_file = "URDF <mimic>" if cfg.model_format == "urdf" else "MJCF joint equality"
        for name in motored:
            if name in self.mimics:
                leader = self.mimics[name].leader
                declared = "[joints] coupled" if name in cfg.coupled_joints else in_file
                raise ConfigError(
                    f"{cfg.path}: joint {name!r} follows {leader!r} ({declared}): it has no "
                    f"motor of its own; name {leader!r} instead (in [joints] actuated, "
                    "torque_limit or a close_torque)"
                )

    def _build_joint_tables(self) -> None:
        cfg, model = self.config, self.model
        moving = [model.names[j] for j in range(1, model.njoints)]
        self.mimics = self._couplings(moving)
        """Coupled joints: follower -> :class:`~wholehand.models.coupling.Mimic` (its leader)."""
        actuated = (
            list(cfg.actuated_joints)
            if cfg.actuated_joints is not None
            else [j for j in moving if j not in self.mimics]
        )
        self._check_named_joints(actuated, moving)
        self.joint_names = moving
        self.actuated_dofs = np.zeros(model.nv, dtype=bool)
        self.tau_max = np.zeros(model.nv)
        for name in actuated:
            idx = model.joints[model.getJointId(name)].idx_v
            self.actuated_dofs[idx] = True
            self.tau_max[idx] = cfg.torque_limits.get(name, cfg.torque_limit_default)
        self.arm_dofs = np.zeros(model.nv, dtype=bool)
        """(n_v,) True for an assembly's arm joints: position-controlled, not allocated."""
        for name in cfg.arm_joints:
            if name in actuated:
                raise ConfigError(
                    f"{cfg.path}: arm joint {name!r} is also an actuated hand joint; the arm's "
                    "joints are position-controlled"
                )
            idx = model.joints[model.getJointId(name)].idx_v
            self.arm_dofs[idx] = True
            self.tau_max[idx] = float(model.effortLimit[idx])
        idx_v = [model.joints[model.getJointId(n)].idx_v for n in moving]
        actuators = [moving[idx_v.index(int(i))] for i in np.flatnonzero(self.actuated_dofs)]
        self.coupling, self.coupling_offset = coupling_matrix(moving, idx_v, actuators, self.mimics)
        """``C`` (n_v, n_a) and ``d`` (n_v,) of ``q = C q_act + d``; actuators in the order of
        ``np.flatnonzero(actuated_dofs)``."""
        # A link is actuated when some driven joint (actuated, or following an actuated one)
        # moves it and it is not declared passive.
        driven = np.any(self.coupling != 0.0, axis=1)
        moved_by_actuated = []
        for jid in self.link_joint:
            support = [j for j in model.supports[int(jid)] if j > 0]
            moved_by_actuated.append(any(driven[model.joints[j].idx_v] for j in support))
        self.link_actuated = np.array(
            [
                m and n not in cfg.passive_links
                for m, n in zip(moved_by_actuated, self.link_names, strict=True)
            ]
        )
        self.q_lower = np.asarray(model.lowerPositionLimit, dtype=float).copy()
        self.q_upper = np.asarray(model.upperPositionLimit, dtype=float).copy()
        for name in moving:
            i = model.joints[model.getJointId(name)].idx_q
            if self.q_lower[i] > self.q_upper[i]:
                raise ConfigError(
                    f"{cfg.model_path}: joint {name!r} has inverted limits: lower "
                    f"{self.q_lower[i]:g} > upper {self.q_upper[i]:g}; swap them in the URDF"
                )

    def link_mesh(self, link: int | str) -> trimesh.Trimesh:
        """Mesh of one link's sampled surface, in its parent-joint frame [m]."""
        i = self.link_index(link) if isinstance(link, str) else link
        return link_mesh_in_joint_frame(self._link_geometry[int(self.link_frame[i])])

    # --- queries ------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.config.name

    @functools.cached_property
    def nq(self) -> int:  # cached: read in every control cycle, and each read crosses into C++
        return int(self.model.nq)

    @functools.cached_property
    def nv(self) -> int:
        return int(self.model.nv)

    def link_index(self, name: str) -> int:
        """Index of a link in :attr:`link_names`."""
        try:
            return self.link_names.index(name)
        except ValueError:
            raise ConfigError(
                f"{name!r} is not a link with geometry of hand {self.name!r}; "
                f"valid links: {self.link_names}"
            ) from None

    @property
    def coupled(self) -> bool:
        """True when some joint follows another (URDF ``<mimic>``)."""
        return bool(self.mimics)

    @property
    def n_actuation(self) -> int:
        """Number of coordinates allocators work in: the actuators (n_a) of a coupled hand,
        every joint (n_v) otherwise (non-actuated ones masked by ``actuated_dofs``)."""
        return int(self.coupling.shape[1]) if self.coupled else self.nv

    def couple(self, q: npt.ArrayLike) -> FloatArray:
        """``q`` (n_q,), or a batch (B, n_q), with every follower joint set from its leader
        (``multiplier * q_leader + offset``); other joints unchanged."""
        q = np.array(q, dtype=float)
        model = self.model
        for follower, m in self.mimics.items():
            i = model.joints[model.getJointId(follower)].idx_q
            leader = model.joints[model.getJointId(m.leader)].idx_q
            q[..., i] = m.multiplier * q[..., leader] + m.offset
        return q

    def joint_torques(self, tau_actuation: FloatArray) -> FloatArray:
        """(n_v,) joint torques [N*m] from an allocator's (n_actuation,) torques: for a coupled
        hand each actuator's torque goes to its own joint (its followers get theirs through the
        coupling), otherwise the torques are already per joint."""
        if not self.coupled:
            return tau_actuation
        tau = np.zeros(self.nv)
        tau[self.actuated_dofs] = tau_actuation
        return tau

    def neutral(self) -> FloatArray:
        """(n_q,) a configuration inside the joint limits (their midpoint where finite), with
        coupled joints set from their leaders."""
        q = pin.neutral(self.model)
        finite = np.isfinite(self.q_lower) & np.isfinite(self.q_upper)
        q[finite] = 0.5 * (self.q_lower[finite] + self.q_upper[finite])
        return self.couple(q)

    def summary(self) -> dict[str, object]:
        """Key facts about the hand, JSON-serialisable."""
        counts = np.bincount(self.samples.link, minlength=len(self.link_names))
        return {
            "name": self.name,
            "model": str(self.config.model_path),
            "nq": self.nq,
            "nv": self.nv,
            "actuated_dofs": int(self.actuated_dofs.sum()),
            "coupled_joints": {f: m.leader for f, m in self.mimics.items()},
            "locked_joints": dict(self.config.locked_joints),
            "links_with_geometry": len(self.link_names),
            "actuated_links": int(self.link_actuated.sum()),
            "fingertip_links": int(self.link_fingertip.sum()),
            "sample_surface": self.config.sample_surface,
            "candidate_points": len(self.samples),
            "points_per_link": dict(zip(self.link_names, counts.tolist(), strict=True)),
            "samples_from_cache": self.samples_from_cache,
        }


def load_hand(name_or_path: str | Path = "allegro_right", **params: object) -> HandModel:
    """Load a shipped hand by name, or a hand folder / hand.toml by path.

    Keyword parameters go to :class:`HandModel` (``n_uniform``, ``density_per_cm2``, ``seed``).
    """
    config = parse_hand_config(resolve_hand_config(name_or_path))
    return HandModel(config, **params)  # type: ignore[arg-type]
