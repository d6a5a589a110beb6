"""Candidate contact points on a hand's links: sampled once per hand and cached on disk.

Each link's sampled surface (collision or visual geometry, ``sample_surface`` of hand.toml) is
sampled uniformly plus by area density (:func:`~wholehand.models.surface.sample_link_surface`),
in the frame of the link's parent joint; with ``outer_surface_only`` the samples buried inside
other collision shapes are dropped (:mod:`wholehand.models.outer_surface`). The samples are
cached under a content hash of the model file, its meshes, the sampling parameters and the link
set.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from wholehand.models import cache
from wholehand.models.outer_surface import find_buried_samples
from wholehand.models.surface import sample_link_surface

if TYPE_CHECKING:
    import pinocchio as pin
    import trimesh

    from wholehand.models.hand_config import HandConfig

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


class SampledHand(Protocol):
    """What sampling reads of a hand (:class:`~wholehand.models.hand.HandModel`)."""

    config: HandConfig
    model: pin.Model
    collision_model: pin.GeometryModel
    visual_model: pin.GeometryModel
    link_names: list[str]
    link_joint: IntArray
    """(L,) Pinocchio joint id of each link's parent joint."""
    parsed_model_path: Path
    sample_params: dict[str, Any]

    def link_mesh(self, link: int | str) -> trimesh.Trimesh:
        """The link's surface in its parent joint's frame [m]."""
        ...


@dataclass(frozen=True)
class SurfaceSamples:
    """Candidate contact points on every link, stacked; rows grouped by link."""

    p_joint: FloatArray
    """(P, 3) points in the frame of their link's parent joint [m]."""
    n_joint: FloatArray
    """(P, 3) outward surface normals of the hand at the points, same frames."""
    link: IntArray
    """(P,) link index of each point."""
    joint: IntArray
    """(P,) Pinocchio joint index of each point's parent joint (0: the hand base)."""

    def __len__(self) -> int:
        return int(self.p_joint.shape[0])


def samples_cache_key(hand: SampledHand) -> str:
    """The content hash the hand's samples are cached under."""
    cfg = hand.config
    sampled = hand.collision_model if cfg.sample_surface == "collision" else hand.visual_model
    meshes = sorted(
        {Path(o.meshPath) for o in sampled.geometryObjects if Path(o.meshPath).is_file()}
    )
    shape = {
        "links": hand.link_names,
        "locked": cfg.locked_joints,
        "outer_surface_only": cfg.outer_surface_only,
    }
    # An MJCF's self-contained copy holds its <include>d files too.
    return cache.content_hash(hand.parsed_model_path, *meshes, hand.sample_params, shape)


def load_or_sample(hand: SampledHand) -> tuple[SurfaceSamples, bool]:
    """The hand's samples from the cache, or sampled and cached; and whether they came from the
    cache."""
    key = samples_cache_key(hand)
    stored = cache.load_arrays(
        "link_samples", key, [f.name for f in dataclasses.fields(SurfaceSamples)]
    )
    if stored is not None:
        return SurfaceSamples(**stored), True
    started = time.perf_counter()
    samples = sample_surfaces(hand)
    cache.save_arrays("link_samples", key, samples.__dict__)
    log.info(
        "sampled %d candidate points on %d links of %s in %.2f s",
        len(samples),
        len(hand.link_names),
        hand.config.name,
        time.perf_counter() - started,
    )
    return samples, False


def sample_surfaces(hand: SampledHand) -> SurfaceSamples:
    """Sample every link's surface (``hand.sample_params``), seeded per link."""
    params = hand.sample_params
    p, n, link, joint = [], [], [], []
    for i in range(len(hand.link_names)):
        pts, normals = sample_link_surface(
            hand.link_mesh(i), params["n_uniform"], params["density_per_cm2"], params["seed"] + i
        )
        p.append(pts)
        n.append(normals)
        link.append(np.full(len(pts), i, dtype=np.intp))
        joint.append(np.full(len(pts), hand.link_joint[i], dtype=np.intp))
    samples = SurfaceSamples(
        p_joint=np.concatenate(p),
        n_joint=np.concatenate(n),
        link=np.concatenate(link),
        joint=np.concatenate(joint),
    )
    if not hand.config.outer_surface_only:
        return samples
    found = find_buried_samples(
        hand.model, hand.collision_model, samples.p_joint, samples.joint, params["seed"]
    )
    if found.skipped_shapes:
        log.warning(
            "%s: outer_surface_only skips %d collision shapes that are not closed surfaces: %s",
            hand.config.path,
            len(found.skipped_shapes),
            found.skipped_shapes,
        )
    keep = ~found.buried
    return SurfaceSamples(**{k: v[keep] for k, v in samples.__dict__.items()})
