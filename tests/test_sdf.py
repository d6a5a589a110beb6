"""Signed distance grids against ground truth: analytic sphere and box distances, analytic
normals, brute-force point-triangle distances and trimesh's inside test on a YCB mesh."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from wholehand.errors import AssetError, ConfigError
from wholehand.models import sdf as sdf_module
from wholehand.models.object_catalogue import ycb_mesh_dir
from wholehand.models.sdf import SignedDistanceGrid
from wholehand.models.sdf_build import MeshDistance

SPACING = 0.002
RADIUS = 0.04
HALF = np.array([0.025, 0.03, 0.05])  # box half extents [m]


def sphere_sdf(p: np.ndarray) -> np.ndarray:
    return np.linalg.norm(p, axis=1) - RADIUS


def box_sdf(p: np.ndarray) -> np.ndarray:
    q = np.abs(p) - HALF
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def random_points(rng: np.random.Generator, n: int, r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Points in random directions at radii uniform in [0, r_max]; returns points and unit dirs."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(0.0, r_max, n)[:, None], d


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.fixture(scope="module")
def sphere_grid() -> SignedDistanceGrid:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    return SignedDistanceGrid.from_mesh(mesh, spacing=SPACING, padding=0.03, use_cache=False)


@pytest.fixture(scope="module")
def box_grid() -> SignedDistanceGrid:
    mesh = trimesh.creation.box(extents=2.0 * HALF)
    return SignedDistanceGrid.from_mesh(mesh, spacing=SPACING, padding=0.03, use_cache=False)


@pytest.fixture(scope="module")
def ycb_mesh() -> trimesh.Trimesh:
    return trimesh.load(ycb_mesh_dir() / "077_rubiks_cube.stl", force="mesh")


@pytest.fixture(scope="module")
def ycb_grid(ycb_mesh: trimesh.Trimesh) -> SignedDistanceGrid:
    return SignedDistanceGrid.from_mesh(ycb_mesh)


# --- analytic ground truth ----------------------------------------------------------------------
def test_grid_covers_mesh_with_padding(sphere_grid: SignedDistanceGrid) -> None:
    lo, hi = sphere_grid.bounds
    assert np.all(lo <= -RADIUS - 0.03 + 1e-12) and np.all(hi >= RADIUS + 0.03 - 1e-12)
    assert sphere_grid.values.dtype == np.float32
    assert sphere_grid.shape == sphere_grid.values.shape


def test_sphere_nodes_match_analytic(sphere_grid: SignedDistanceGrid) -> None:
    truth = sphere_sdf(sphere_grid.node_positions())
    err = np.abs(sphere_grid.values.reshape(-1) - truth)
    band = np.abs(truth) <= 0.015
    # Near the surface: exact up to the icosphere's faceting (< 0.05 mm at R = 4 cm).
    assert err[band].max() < 1e-4
    assert err.max() < SPACING  # everywhere, including the far field
    assert np.all(
        np.sign(sphere_grid.values.reshape(-1)[np.abs(truth) > 1e-4])
        == np.sign(truth[np.abs(truth) > 1e-4])
    )


def test_sphere_query_matches_analytic(sphere_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(0)
    p, _ = random_points(rng, 5000, RADIUS + 0.03)
    truth = sphere_sdf(p)
    d = sphere_grid.query(p)
    assert np.abs(d - truth).max() < SPACING
    near = np.abs(truth) < 0.01
    assert np.abs(d - truth)[near].max() < 2e-4
    flipped = (d < 0) != (truth < 0)
    assert not flipped.any() or np.abs(truth[flipped]).max() < 2e-4


def test_box_query_matches_analytic(box_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(-HALF - 0.03, HALF + 0.03, size=(5000, 3))
    truth = box_sdf(p)
    d = box_grid.query(p)
    # Trilinear interpolation of the exact node values; the error comes only from the creases
    # of the box SDF (edges outside, medial planes inside).
    assert np.abs(d - truth).max() < 0.5 * SPACING
    nodes = box_grid.node_positions()
    assert np.abs(box_grid.values.reshape(-1) - box_sdf(nodes)).max() < 1e-6


def test_exact_at_nodes(box_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(2)
    idx = rng.integers(0, np.array(box_grid.shape), size=(500, 3))
    d = box_grid.query(box_grid.node_positions(idx))
    np.testing.assert_allclose(d, box_grid.values[idx[:, 0], idx[:, 1], idx[:, 2]], atol=1e-7)


def test_linear_field_is_reproduced_exactly() -> None:
    """Trilinear interpolation reproduces an affine field and its gradient exactly."""
    a, b = np.array([0.3, -0.5, 0.8]), 0.01
    grid = SignedDistanceGrid(
        origin=np.array([-0.1, -0.2, 0.0]), spacing=0.01, values=np.zeros((21, 31, 11))
    )
    values = (grid.node_positions() @ a + b).reshape(grid.shape)
    grid = SignedDistanceGrid(origin=grid.origin, spacing=grid.spacing, values=values)
    rng = np.random.default_rng(3)
    p = rng.uniform(grid.bounds[0], grid.bounds[1], size=(1000, 3))
    d, g = grid.query_with_gradient(p)
    np.testing.assert_allclose(d, p @ a + b, atol=1e-6)
    np.testing.assert_allclose(g, np.tile(a / np.linalg.norm(a), (len(p), 1)), atol=1e-5)


def test_sphere_gradient_is_radial(sphere_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(4)
    p, direction = random_points(rng, 3000, RADIUS + 0.03)
    truth = sphere_sdf(p)
    d, g = sphere_grid.query_with_gradient(p)
    np.testing.assert_array_equal(d, sphere_grid.query(p))
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-5)
    near = np.abs(truth) < 0.01
    # The icosphere's facets tilt the true normal by up to ~2 degrees from radial.
    assert angle_deg(g[near], direction[near]).max() < 4.0


def test_box_gradient_is_face_normal(box_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(5)
    p = rng.uniform(-HALF - 0.01, HALF + 0.01, size=(5000, 3))
    q = np.abs(p) - HALF
    order = np.sort(q, axis=1)
    # Points whose nearest feature is clearly the face along the largest q: more than two cells
    # from the edge regions outside and from the medial planes inside.
    clear = (
        (order[:, 2] - order[:, 1] > 2 * SPACING)
        & (order[:, 1] < -2 * SPACING)
        & (np.abs(order[:, 2]) < 0.01)
    )
    axis = np.argmax(q, axis=1)
    normal = np.zeros_like(p)
    normal[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis])
    _, g = box_grid.query_with_gradient(p[clear])
    assert clear.sum() > 500
    assert angle_deg(g, normal[clear]).max() < 0.5


def test_gradient_matches_finite_differences(sphere_grid: SignedDistanceGrid) -> None:
    """The analytic gradient of the interpolant equals central differences of ``query``."""
    rng = np.random.default_rng(6)
    p, _ = random_points(rng, 500, RADIUS + 0.02)
    frac = (p - sphere_grid.origin) / SPACING % 1.0
    p = p[np.all((frac > 0.05) & (frac < 0.95), axis=1)]  # stay inside one cell
    _, g = sphere_grid.query_with_gradient(p)
    h = 1e-5
    fd = np.stack(
        [
            (sphere_grid.query(p + h * e) - sphere_grid.query(p - h * e)) / (2 * h)
            for e in np.eye(3)
        ],
        axis=1,
    )
    assert angle_deg(g, fd).max() < 0.05


def test_query_nearest_bounds(sphere_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(7)
    p, _ = random_points(rng, 3000, RADIUS + 0.03)
    nearest = sphere_grid.query_nearest(p)
    truth = sphere_sdf(p)
    band = np.abs(truth) < 0.01  # exact node values: off by at most the distance to the node
    assert np.abs(nearest - truth)[band].max() <= np.sqrt(3) / 2 * SPACING + 1e-4
    assert np.abs(nearest - sphere_grid.query(p)).max() <= SPACING


# --- YCB mesh: sign against trimesh, distance against brute force -------------------------------
def test_ycb_sign_matches_trimesh_contains(
    ycb_mesh: trimesh.Trimesh, ycb_grid: SignedDistanceGrid
) -> None:
    rng = np.random.default_rng(8)
    # Grid nodes: the stored sign is exact.
    idx = rng.integers(0, np.array(ycb_grid.shape), size=(1000, 3))
    nodes = ycb_grid.node_positions(idx)
    values = ycb_grid.values[idx[:, 0], idx[:, 1], idx[:, 2]]
    inside = ycb_mesh.contains(nodes)
    assert inside.sum() > 100 and (~inside).sum() > 100
    sure = np.abs(values) > 1e-5  # contains() is unreliable on the surface itself
    np.testing.assert_array_equal((values < 0.0)[sure], inside[sure])
    # Points near the surface: the pseudo-normal sign of the exact distance.
    near = ycb_mesh.sample(600, seed=8) + rng.normal(scale=0.003, size=(600, 3))
    dist = MeshDistance(np.asarray(ycb_mesh.vertices), ycb_mesh.faces, 0.001)
    exact = dist.signed_distance(near).distance
    near_inside = ycb_mesh.contains(near)
    sure = np.abs(exact) > 1e-5
    np.testing.assert_array_equal((exact < 0.0)[sure], near_inside[sure])
    # Interpolated queries: right sign wherever they are more than a cell from zero.
    d = ycb_grid.query(near)
    far = np.abs(d) > SPACING
    np.testing.assert_array_equal((d < 0.0)[far], near_inside[far])


def test_ycb_band_nodes_match_brute_force(
    ycb_mesh: trimesh.Trimesh, ycb_grid: SignedDistanceGrid
) -> None:
    values = ycb_grid.values.reshape(-1)
    rng = np.random.default_rng(9)
    band = np.flatnonzero(np.abs(values) < 0.012)
    pick = rng.choice(band, size=60, replace=False)
    nodes = ycb_grid.node_positions(np.stack(np.unravel_index(pick, ycb_grid.shape), axis=1))
    dist = MeshDistance(np.asarray(ycb_mesh.vertices), ycb_mesh.faces, sample_step=0.001)
    n_faces = len(ycb_mesh.faces)
    brute = np.array(
        [
            np.sqrt(
                np.min(
                    np.sum(
                        dist._point_triangle(
                            np.repeat(x[None], n_faces, axis=0), np.arange(n_faces)
                        )[0]
                        ** 2,
                        axis=1,
                    )
                )
            )
            for x in nodes
        ]
    )
    np.testing.assert_allclose(np.abs(values[pick]), brute, atol=1e-6)


def test_mesh_distance_closest_points_lie_on_surface(ycb_mesh: trimesh.Trimesh) -> None:
    rng = np.random.default_rng(10)
    p = ycb_mesh.sample(40, seed=10) + rng.normal(scale=0.005, size=(40, 3))
    dist = MeshDistance(np.asarray(ycb_mesh.vertices), ycb_mesh.faces, 0.001)
    d, closest, face = dist.signed_distance(p)
    np.testing.assert_allclose(np.linalg.norm(p - closest, axis=1), np.abs(d), atol=1e-12)
    # The closest point lies on the reported face.
    on_face, _ = dist._point_triangle(closest, face)
    assert np.max(np.sum(on_face**2, axis=1)) < 1e-20


# --- cache ----------------------------------------------------------------------------------------
def test_second_build_is_a_cache_hit(fresh_cache, monkeypatch: pytest.MonkeyPatch) -> None:
    mesh = trimesh.creation.box(extents=(0.03, 0.04, 0.05))
    first = SignedDistanceGrid.from_mesh(mesh, spacing=0.004, padding=0.01)
    assert list((fresh_cache / "sdf").glob("*.npz"))

    def no_compute(*args, **kwargs):
        raise AssertionError("the SDF was recomputed despite a cache entry")

    monkeypatch.setattr(sdf_module, "compute_grid_values", no_compute)
    second = SignedDistanceGrid.from_mesh(mesh, spacing=0.004, padding=0.01)
    np.testing.assert_array_equal(first.values, second.values)
    np.testing.assert_array_equal(first.origin, second.origin)
    # Another spacing, or a moved vertex, is another key: it must compute (and here, raise).
    with pytest.raises(AssertionError, match="recomputed"):
        SignedDistanceGrid.from_mesh(mesh, spacing=0.005, padding=0.01)
    moved = mesh.copy()
    moved.vertices[0] += 1e-6
    with pytest.raises(AssertionError, match="recomputed"):
        SignedDistanceGrid.from_mesh(moved, spacing=0.004, padding=0.01)


def test_arrays_round_trip(box_grid: SignedDistanceGrid) -> None:
    again = SignedDistanceGrid.from_arrays(box_grid.to_arrays())
    np.testing.assert_array_equal(again.values, box_grid.values)
    assert again.spacing == box_grid.spacing


# --- outside the grid, NaN and bad input ----------------------------------------------------------
def test_points_outside_grid_get_conservative_distance(sphere_grid: SignedDistanceGrid) -> None:
    rng = np.random.default_rng(11)
    p, direction = random_points(rng, 500, 1.0)
    p += direction * 0.08  # at least 4 cm outside the sphere
    lo, hi = sphere_grid.bounds
    outside = np.any((p < lo) | (p > hi), axis=1)
    assert outside.sum() > 400
    d, g = sphere_grid.query_with_gradient(p[outside])
    truth = sphere_sdf(p[outside])
    assert np.all(d >= truth - 1e-4)  # an upper bound of the true distance
    assert np.all(d >= 0.029)  # at least about the padding: never a contact
    assert np.all(np.sum(g * direction[outside], axis=1) > 0.0)  # pointing away from the object
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(sphere_grid.query_nearest(p[outside]), d, atol=SPACING)
    # Continuous across the boundary of the grid box.
    edge = np.array([[hi[0], 0.0, 0.0]])
    inner, outer = sphere_grid.query(edge - [1e-7, 0, 0]), sphere_grid.query(edge + [1e-7, 0, 0])
    np.testing.assert_allclose(inner, outer, atol=1e-6)
    assert np.isinf(sphere_grid.query(np.array([[np.inf, 0.0, 0.0]])))[0]


def test_nan_points_propagate_without_warnings(sphere_grid: SignedDistanceGrid) -> None:
    p = np.array([[0.0, 0.0, 0.05], [np.nan, 0.0, 0.0], [0.0, np.nan, 0.2], [0.01, 0.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = sphere_grid.query(p)
        d2, g = sphere_grid.query_with_gradient(p)
        dn = sphere_grid.query_nearest(p)
    assert np.isnan(d[1:3]).all() and np.isnan(d2[1:3]).all() and np.isnan(dn[1:3]).all()
    assert np.isnan(g[1:3]).all()
    assert np.isfinite(d[[0, 3]]).all() and np.isfinite(g[[0, 3]]).all()
    np.testing.assert_allclose(d[[0, 3]], [0.01, -0.03], atol=2e-4)


@pytest.mark.parametrize("shape", [(3,), (10, 2), (2, 3, 1)])
def test_bad_point_shapes_raise(sphere_grid: SignedDistanceGrid, shape: tuple[int, ...]) -> None:
    with pytest.raises(ConfigError, match=r"\(P, 3\)"):
        sphere_grid.query(np.zeros(shape))
    with pytest.raises(ConfigError):
        sphere_grid.query_with_gradient(np.zeros(shape))


def test_empty_query_returns_empty(sphere_grid: SignedDistanceGrid) -> None:
    d, g = sphere_grid.query_with_gradient(np.zeros((0, 3)))
    assert (
        d.shape == (0,) and g.shape == (0, 3) and sphere_grid.query(np.zeros((0, 3))).shape == (0,)
    )


def test_values_are_read_only(box_grid: SignedDistanceGrid) -> None:
    with pytest.raises(ValueError):
        box_grid.values[0, 0, 0] = 1.0


def test_non_watertight_mesh_raises() -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    open_box = trimesh.Trimesh(box.vertices, box.faces[1:])
    with pytest.raises(AssetError, match="watertight"):
        SignedDistanceGrid.from_mesh(open_box, use_cache=False)


def test_inside_out_mesh_raises() -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    box.invert()
    with pytest.raises(AssetError, match="inside out"):
        SignedDistanceGrid.from_mesh(box, use_cache=False)


@pytest.mark.parametrize(
    "kwargs", [{"spacing": 0.0}, {"spacing": -0.002}, {"padding": -0.01}, {"spacing": float("nan")}]
)
def test_bad_build_parameters_raise(kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        SignedDistanceGrid.from_mesh(trimesh.creation.box(extents=(0.05, 0.05, 0.05)), **kwargs)


def test_grid_too_large_raises() -> None:
    box_mm = trimesh.creation.box(extents=(50.0, 50.0, 100.0))  # millimetres by mistake
    with pytest.raises(ConfigError, match="nodes"):
        SignedDistanceGrid.from_mesh(box_mm, use_cache=False)


def test_bad_grid_arrays_raise() -> None:
    with pytest.raises(ConfigError):
        SignedDistanceGrid(origin=np.zeros(2), spacing=0.01, values=np.zeros((2, 2, 2)))
    with pytest.raises(ConfigError):
        SignedDistanceGrid(origin=np.zeros(3), spacing=0.0, values=np.zeros((2, 2, 2)))
    with pytest.raises(ConfigError):
        SignedDistanceGrid(origin=np.zeros(3), spacing=0.01, values=np.zeros((2, 2)))
    with pytest.raises(ConfigError):
        SignedDistanceGrid(origin=np.zeros(3), spacing=0.01, values=np.full((2, 2, 2), np.nan))
