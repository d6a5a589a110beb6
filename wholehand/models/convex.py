"""Convex decomposition of object meshes for simulation, with an on-disk cache.

MuJoCo collides a mesh geom as its convex hull, which fills the cavity of a cup or the jaw gap of a
clamp. A non-convex object therefore collides as a set of convex parts computed once by CoACD
(approximate convex decomposition, ``pip install coacd``) and stored as arrays:

- in ``objects/decompositions/<name>-<key16>.npz``, shipped for the paper's five objects so that
  tests and studies never wait for CoACD (see :func:`ship_decompositions`);
- else in the wholehand cache (``$WHOLEHAND_CACHE/convex_decomposition/<key>.npz``).

``key`` is the content hash (:func:`wholehand.models.cache.content_hash`) of the mesh vertices and
faces and of the CoACD parameters, so a changed mesh or parameter never hits a stale entry. Shipped
files and cache entries are made by the same function, :func:`convex_decomposition`.

Run ``python -m wholehand.models.convex 006_mustard_bottle ...`` to (re)make shipped files.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import AssetError, ConfigError
from wholehand.models import cache
from wholehand.models.object_catalogue import PAPER_OBJECTS

if TYPE_CHECKING:
    import trimesh

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

CACHE_KIND = "convex_decomposition"
"""Sub-folder of the wholehand cache holding decompositions."""


DEFAULT_PARAMS: dict[str, Any] = {
    "threshold": 0.05,
    "max_convex_hull": 32,
    "preprocess_mode": "auto",
    "preprocess_resolution": 50,
    "resolution": 2000,
    "mcts_nodes": 20,
    "mcts_iterations": 150,
    "mcts_max_depth": 3,
    "merge": True,
    "seed": 0,
}
"""CoACD parameters. ``threshold`` is the concavity tolerance (CoACD's concavity metric, relative
to the mesh size): 0.05 keeps the cavity of the YCB cup (065-f) and the jaw gap of the clamp open
(about 1 % of the free space inside their convex hulls ends up inside a part, against 100 % for a
single hull), while ``max_convex_hull`` = 32 bounds the number of parts, since the collision cost
per step grows with it (threshold 0.1 with at most 24 parts left 11 % of the clamp's gap filled)."""


def shipped_dir() -> Path:
    """Folder of the precomputed decompositions shipped with wholehand."""
    import wholehand_objects

    return Path(wholehand_objects.__file__).parent / "decompositions"


@dataclass(frozen=True)
class ConvexDecomposition:
    """Convex parts of a mesh, stacked; every part is one closed convex polytope.

    Part ``i`` owns vertex rows ``vertex_start[i]:vertex_start[i] + part_vertices[i]`` and face rows
    likewise; face indices are local to their part.
    """

    vertices: FloatArray
    """(V, 3) vertices of all parts, in the mesh frame [m]."""
    faces: IntArray
    """(F, 3) triangles of all parts, indices local to their part."""
    part_vertices: IntArray
    """(P,) number of vertices of each part."""
    part_faces: IntArray
    """(P,) number of faces of each part."""
    key: str = ""
    """Content hash of the mesh and parameters that produced it."""
    source: str = ""
    """Where it came from: ``"shipped"``, ``"cache"`` or ``"computed"``."""
    seconds: float = 0.0
    """Time CoACD took when it was computed [s] (0 when loaded)."""
    params: dict[str, Any] = field(default_factory=dict)
    """The CoACD parameters."""

    def __len__(self) -> int:
        return int(self.part_vertices.shape[0])

    def parts(self) -> list[tuple[FloatArray, IntArray]]:
        """(vertices (V_i, 3), faces (F_i, 3)) of each part."""
        v_end = np.cumsum(self.part_vertices)
        f_end = np.cumsum(self.part_faces)
        out = []
        for i in range(len(self)):
            v0, f0 = v_end[i] - self.part_vertices[i], f_end[i] - self.part_faces[i]
            out.append((self.vertices[v0 : v_end[i]], self.faces[f0 : f_end[i]]))
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays stored on disk."""
        return {
            "vertices": self.vertices,
            "faces": self.faces,
            "part_vertices": self.part_vertices,
            "part_faces": self.part_faces,
        }

    @classmethod
    def from_parts(
        cls, parts: list[tuple[np.ndarray, np.ndarray]], **meta: Any
    ) -> ConvexDecomposition:
        """Stack a list of (vertices, faces) parts."""
        if not parts:
            raise AssetError("a convex decomposition needs at least one part, got none")
        return cls(
            vertices=np.concatenate([np.asarray(v, dtype=float) for v, _ in parts]),
            faces=np.concatenate([np.asarray(f, dtype=np.int64) for _, f in parts]),
            part_vertices=np.array([len(v) for v, _ in parts], dtype=np.int64),
            part_faces=np.array([len(f) for _, f in parts], dtype=np.int64),
            **meta,
        )


def _params(overrides: dict[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(overrides) - set(DEFAULT_PARAMS))
    if unknown:
        raise ConfigError(
            f"unknown CoACD parameters {unknown}; valid parameters: {sorted(DEFAULT_PARAMS)}"
        )
    params = {**DEFAULT_PARAMS, **overrides}
    if not 0.0 < float(params["threshold"]) <= 1.0:
        raise ConfigError(f"CoACD threshold must be in (0, 1], got {params['threshold']!r}")
    return params


def decomposition_key(mesh: trimesh.Trimesh, params: dict[str, Any]) -> str:
    """Content hash of a mesh (vertices and faces) and the full CoACD parameters."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    return cache.content_hash(
        "coacd", vertices.tobytes(), faces.tobytes(), {"params": _params(params)}
    )


def _shipped_path(name: str, key: str, folder: Path | None = None) -> Path:
    return (folder or shipped_dir()) / f"{name}-{key[:16]}.npz"


def shipped_decomposition_file(name: str, mesh: trimesh.Trimesh, **params: Any) -> Path:
    """Where the shipped decomposition of ``mesh`` (named ``name``) with these CoACD parameters
    is, or would be; it is used only if it exists (it is never computed here)."""
    return _shipped_path(name, decomposition_key(mesh, _params(params)))


def _run_coacd(
    mesh: trimesh.Trimesh, params: dict[str, Any]
) -> list[tuple[np.ndarray, np.ndarray]]:
    try:
        import coacd
    except ImportError as err:
        raise AssetError(
            "convex decomposition of a mesh object needs CoACD: `pip install coacd`; or simulate "
            "it as a single convex hull (collision='hull'), which closes its cavities"
        ) from err
    coacd.set_log_level("error")
    cmesh = coacd.Mesh(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=int))
    try:
        parts = coacd.run_coacd(cmesh, **params)
    except Exception as err:  # CoACD raises bare RuntimeErrors from C++
        raise AssetError(f"CoACD failed on the mesh ({err}); try another threshold") from err
    return [(np.asarray(v, dtype=float), np.asarray(f, dtype=np.int64)) for v, f in parts]


def convex_decomposition(
    mesh: trimesh.Trimesh, name: str | None = None, **params: Any
) -> ConvexDecomposition:
    """Convex parts of ``mesh``: shipped file, else cache entry, else CoACD (then cached).

    Args:
        mesh: the object mesh in its own frame [m].
        name: object name, used to find a shipped decomposition (``<name>-<key16>.npz``).
        **params: CoACD parameters overriding :data:`DEFAULT_PARAMS`.

    CoACD takes 7-130 s for a 16k-face YCB mesh (2-core machine); the result is cached.
    """
    full = _params(params)
    key = decomposition_key(mesh, full)
    if name is not None:
        path = _shipped_path(name, key)
        if path.is_file():
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in ("vertices", "faces", "part_vertices", "part_faces")}
            return ConvexDecomposition(**arrays, key=key, source="shipped", params=full)
    stored: dict[str, Any] | None = cache.load_arrays(
        CACHE_KIND, key, ("vertices", "faces", "part_vertices", "part_faces")
    )
    if stored is not None:
        return ConvexDecomposition(**stored, key=key, source="cache", params=full)

    what = name or "mesh"
    log.info(
        "convex decomposition of %s (%d faces) with CoACD threshold %.3g; this takes up to a "
        "minute, once (cached)",
        what,
        len(mesh.faces),
        full["threshold"],
    )
    started = time.perf_counter()
    parts = _run_coacd(mesh, full)
    seconds = time.perf_counter() - started
    result = ConvexDecomposition.from_parts(
        parts, key=key, source="computed", seconds=seconds, params=full
    )
    cache.save_arrays(CACHE_KIND, key, result.arrays())
    log.info("%s: %d convex parts in %.1f s", what, len(result), seconds)
    return result


def ship_decompositions(
    names: tuple[str, ...] | list[str] = PAPER_OBJECTS, folder: Path | None = None, **params: Any
) -> dict[str, dict[str, Any]]:
    """Compute (or reuse) the decompositions of named objects and write them as shipped files.

    Returns, per name, the file written, the number of parts and the CoACD time [s].
    """
    from wholehand.models.object_catalogue import load_object

    folder = folder or shipped_dir()
    folder.mkdir(parents=True, exist_ok=True)
    report: dict[str, dict[str, Any]] = {}
    for name in names:
        obj = load_object(name)
        dec = convex_decomposition(obj.mesh, name=name, **params)
        path = _shipped_path(name, dec.key, folder)
        for old in folder.glob(f"{name}-*.npz"):
            if old != path:
                old.unlink()
        np.savez_compressed(path, allow_pickle=False, **dec.arrays())
        report[name] = {"file": str(path), "parts": len(dec), "seconds": round(dec.seconds, 1)}
        log.info("%s: %d parts -> %s", name, len(dec), path)
    return report


def main(argv: list[str] | None = None) -> None:
    """Command line: write shipped decompositions (defaults: the paper's five objects)."""
    import json

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("names", nargs="*", default=list(PAPER_OBJECTS))
    parser.add_argument("--threshold", type=float, default=DEFAULT_PARAMS["threshold"])
    parser.add_argument("--folder", type=Path, default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    report = ship_decompositions(args.names, args.folder, threshold=args.threshold)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
