"""Thin walls: the measured wall thickness against known plates and tubes, and the grid that
``sdf_spacing="auto"`` builds against the exact signed distance of the mesh."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import trimesh

from wholehand.bench.thin_walls import _TILT, grid_errors
from wholehand.errors import ConfigError
from wholehand.models.objects import AUTO_SPACING, ObjectModel
from wholehand.models.sdf import DEFAULT_SPACING, MAX_GRID_NODES
from wholehand.models.walls import MIN_AUTO_SPACING, spacing_for_wall, thinnest_wall


def tilted_plate(wall: float, side: float = 0.1) -> trimesh.Trimesh:
    plate = trimesh.creation.box(extents=(side, 0.8 * side, wall))
    plate.apply_transform(_TILT)
    return plate


@pytest.mark.parametrize("wall", [0.002, 0.004, 0.012])
def test_thinnest_wall_of_a_plate_is_its_thickness(wall: float) -> None:
    # 2 % of a plate's surface is its rims (thickness: the plate's width); the rest, its faces.
    assert thinnest_wall(tilted_plate(wall)) == pytest.approx(wall, abs=1e-7)


def test_thinnest_wall_of_a_tube_is_its_wall() -> None:
    # Rays from the faceted outer wall cross to the inner one: 3 mm up to the facets' sag.
    tube = trimesh.creation.annulus(r_min=0.037, r_max=0.04, height=0.09, sections=96)
    assert thinnest_wall(tube) == pytest.approx(0.003, abs=5e-5)


def test_thinnest_wall_of_a_solid_is_its_smallest_width() -> None:
    cube = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    assert thinnest_wall(cube) == pytest.approx(0.05, abs=1e-7)


def test_spacing_for_wall_puts_three_cells_across_and_stays_in_bounds() -> None:
    assert spacing_for_wall(0.003, DEFAULT_SPACING) == pytest.approx(0.001)
    assert spacing_for_wall(0.05, DEFAULT_SPACING) == DEFAULT_SPACING
    assert spacing_for_wall(1e-4, DEFAULT_SPACING) == MIN_AUTO_SPACING


def test_auto_spacing_gets_signs_and_normals_right_inside_a_thin_plate() -> None:
    # Ground truth: the exact signed distance and the direction to the closest mesh point.
    wall = 0.003
    coarse = ObjectModel.from_trimesh(tilted_plate(wall), "plate-coarse")
    fine = ObjectModel.from_trimesh(tilted_plate(wall), "plate-auto", sdf_spacing=AUTO_SPACING)
    assert fine.grid_spacing == pytest.approx(wall / 3, rel=1e-6)
    before = grid_errors(coarse, wall, points=1500, seed=1)["inside"]
    after = grid_errors(fine, wall, points=1500, seed=1)["inside"]
    # The default 2 mm grid blends the two faces of a 3 mm wall: wrong signs, flipped normals.
    assert before["normal_flipped_pct"] > 0.0 and before["wrong_sign_pct"] > 2.0
    assert after["normal_flipped_pct"] == 0.0
    assert after["wrong_sign_pct"] < 1.0
    assert after["normal_off_pct"] < 0.5 * before["normal_off_pct"]


def test_auto_spacing_leaves_thick_objects_at_the_default() -> None:
    cube = ObjectModel.box((0.05, 0.05, 0.05), sdf_spacing=AUTO_SPACING)
    assert cube.grid_spacing == DEFAULT_SPACING


def test_auto_spacing_coarsens_past_the_node_limit(caplog: pytest.LogCaptureFixture) -> None:
    big = ObjectModel.from_trimesh(tilted_plate(0.002, side=1.0), "sheet", sdf_spacing="auto")
    with caplog.at_level(logging.WARNING, logger="wholehand.models.objects"):
        spacing = big.grid_spacing
    assert spacing > 0.002 / 3
    lo, hi = big.mesh.bounds
    nodes = np.prod(np.ceil((hi - lo + 2 * big.sdf_padding) / spacing) + 1)
    assert nodes <= MAX_GRID_NODES
    assert "sheet" in caplog.text and "would pass" in caplog.text


@pytest.mark.parametrize("bad", ["fine", -0.001, float("nan")])
def test_bad_sdf_spacing_names_the_choices(bad: object) -> None:
    with pytest.raises(ConfigError, match="sdf_spacing must be > 0 .m. or 'auto'"):
        ObjectModel.box((0.05, 0.05, 0.05), sdf_spacing=bad)  # type: ignore[arg-type]
