"""Bounding spheres of groups of hand samples, for culls that skip whole groups at once.

Grasp synthesis (:mod:`wholehand.grasps.synthesis_energy`) places thousands of hand surface
samples per start and step; most lie far from the object, the table and the other fingers. A
group's sphere, placed with its joint, says for all of its samples at once that they are out of
reach. Sample positions are given in their joints' frames [m]."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


class Spheres(NamedTuple):
    """Bounding spheres of groups of consecutive items (hand samples, or smaller groups): group
    ``g`` holds items ``bounds[g]:bounds[g + 1]``; its sphere's centre (G, 3) [m] is given in
    the frame of joint ``joint[g]``, and its radius (G,) [m] bounds the distance from it of
    every sample the group holds."""

    bounds: IntArray
    centre: FloatArray
    joint: IntArray
    radius: FloatArray


def bounding_sphere(points: FloatArray) -> tuple[FloatArray, float]:
    """A sphere around ``points`` (N, 3): the centre of their box, the farthest one's distance
    (a little more, so that rounding never leaves a point out)."""
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    return centre, float(np.linalg.norm(points - centre, axis=1).max()) * (1.0 + 1e-9) + 1e-12


def clusters(
    p_joint: FloatArray, joint: IntArray, link: IntArray, most: int
) -> tuple[IntArray, Spheres]:
    """Every sample in compact groups of at most ``most`` of one link: each link's samples
    halved across their widest extent until each part is small enough (a k-d split, so that
    the groups' spheres are about as small as their samples' spacing allows). Returns the
    samples in group order and the groups' spheres (bounds into that order)."""
    order: list[IntArray] = []
    made: list[tuple[FloatArray, float]] = []
    on_joint: list[int] = []

    def split(rows: IntArray) -> None:
        points = p_joint[rows]
        if rows.size <= most:
            order.append(rows)
            made.append(bounding_sphere(points))
            on_joint.append(int(joint[rows[0]]))
            return
        axis = int(np.argmax(points.max(axis=0) - points.min(axis=0)))
        ranked = rows[np.argsort(points[:, axis], kind="stable")]
        split(ranked[: rows.size // 2])
        split(ranked[rows.size // 2 :])

    for k in np.unique(link):
        split(np.flatnonzero(link == k).astype(np.intp))
    bounds = np.concatenate(([0], np.cumsum([rows.size for rows in order]))).astype(np.intp)
    spheres = Spheres(
        bounds,
        np.array([c for c, _ in made]).reshape(-1, 3),
        np.asarray(on_joint, dtype=np.intp),
        np.array([r for _, r in made]),
    )
    return np.concatenate(order).astype(np.intp), spheres


def chunks_along_links(
    p_joint: FloatArray,
    joint: IntArray,
    link: IntArray,
    rows: IntArray,
    finger: IntArray,
    most: int,
) -> tuple[IntArray, IntArray, Spheres, Spheres]:
    """The samples ``rows`` (with their ``finger``) ordered by link and, within a link, along
    its longest extent, cut into chunks of at most ``most``; the chunks' spheres (over
    the rows) and the links' (over the chunks)."""
    out_rows, out_finger = [], []
    chunk_bounds, link_bounds = [0], [0]
    chunk_spheres, link_spheres = [], []
    for k in np.unique(link[rows]):
        on = np.flatnonzero(link[rows] == k)
        points = p_joint[rows[on]]
        axis = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)[2][0]
        on = on[np.argsort(points @ axis, kind="stable")]
        for part in range(0, on.size, most):
            piece = on[part : part + most]
            out_rows.append(rows[piece])
            out_finger.append(finger[piece])
            chunk_bounds.append(chunk_bounds[-1] + piece.size)
            chunk_spheres.append(bounding_sphere(p_joint[rows[piece]]))
        link_bounds.append(len(chunk_spheres))
        link_spheres.append(bounding_sphere(points))
    joint_of = [int(joint[rows[link[rows] == k][0]]) for k in np.unique(link[rows])]
    chunk_joint = np.repeat(joint_of, np.diff(link_bounds)).astype(np.intp)

    def spheres(bounds: list[int], made: list[tuple[FloatArray, float]], on: IntArray) -> Spheres:
        return Spheres(
            np.asarray(bounds, dtype=np.intp),
            np.array([c for c, _ in made]).reshape(-1, 3),
            on,
            np.array([r for _, r in made]),
        )

    order = np.concatenate(out_rows).astype(np.intp) if out_rows else rows
    fingers = np.concatenate(out_finger).astype(np.intp) if out_finger else finger
    chunks = spheres(chunk_bounds, chunk_spheres, chunk_joint)
    links = spheres(link_bounds, link_spheres, np.asarray(joint_of, dtype=np.intp))
    return order, fingers, chunks, links
