"""Object models: primitives against analytic mass properties, mesh loading and repair, the YCB
registry, and every kind of bad input."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import trimesh

from wholehand.errors import AssetError, ConfigError
from wholehand.models import objects
from wholehand.models.mesh_repair import repair_mesh
from wholehand.models.object_catalogue import (
    PAPER_OBJECTS,
    available_objects,
    load_object,
    parse_primitive_spec,
    ycb_mesh_dir,
    ycb_registry,
)
from wholehand.models.objects import DEFAULT_DENSITY, ObjectModel
from wholehand.models.sdf import SignedDistanceGrid
from wholehand.models.sdf_build import MeshDistance


def write_mesh(mesh: trimesh.Trimesh, path: Path) -> Path:
    mesh.export(path)
    return path


def mesh_mass_properties(obj: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """COM and inertia of the object's mesh with uniform density, scaled to its mass."""
    return obj.mesh.center_mass, obj.mesh.moment_inertia / obj.mesh.mass * obj.mass


# --- primitives ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("obj", "volume", "extents"),
    [
        (ObjectModel.box((0.05, 0.06, 0.1), mass=0.3), 0.05 * 0.06 * 0.1, (0.05, 0.06, 0.1)),
        (ObjectModel.sphere(0.04, mass=0.3), 4 / 3 * np.pi * 0.04**3, (0.08, 0.08, 0.08)),
        (ObjectModel.cylinder(0.03, 0.12, mass=0.3), np.pi * 0.03**2 * 0.12, (0.06, 0.06, 0.12)),
        (
            ObjectModel.capsule(0.02, 0.08, mass=0.3),
            np.pi * 0.02**2 * 0.08 + 4 / 3 * np.pi * 0.02**3,
            (0.04, 0.04, 0.12),
        ),
    ],
    ids=["box", "sphere", "cylinder", "capsule"],
)
def test_primitives_match_analytic_geometry_and_mass_properties(
    obj: ObjectModel, volume: float, extents: tuple[float, float, float]
) -> None:
    assert obj.mesh.is_watertight
    np.testing.assert_allclose(obj.extents, extents, rtol=1e-3)
    np.testing.assert_allclose(obj.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)  # centred
    assert obj.volume == pytest.approx(volume, rel=5e-3)  # faceting of round primitives
    assert obj.mass == 0.3
    np.testing.assert_array_equal(obj.com, 0.0)
    # Analytic inertia agrees with the inertia of the (finely faceted) mesh.
    com_mesh, inertia_mesh = mesh_mass_properties(obj)
    np.testing.assert_allclose(com_mesh, 0.0, atol=1e-6)
    np.testing.assert_allclose(obj.inertia, inertia_mesh, rtol=5e-3, atol=1e-12)
    assert obj.kind in obj.name


def test_primitive_dimensions_for_other_modules() -> None:
    assert ObjectModel.box((0.05, 0.06, 0.1)).dimensions == {"size": (0.05, 0.06, 0.1)}
    assert ObjectModel.sphere(0.04).dimensions == {"radius": 0.04}
    assert ObjectModel.cylinder(0.03, 0.12).dimensions == {"radius": 0.03, "height": 0.12}
    assert ObjectModel.capsule(0.02, 0.08).dimensions == {"radius": 0.02, "length": 0.08}


def test_box_inertia_is_textbook() -> None:
    obj = ObjectModel.box((0.1, 0.2, 0.3), mass=1.2)
    expected = 1.2 / 12 * np.diag([0.2**2 + 0.3**2, 0.1**2 + 0.3**2, 0.1**2 + 0.2**2])
    np.testing.assert_allclose(obj.inertia, expected)


def test_mass_from_mass_density_or_default() -> None:
    volume = 0.05**3
    assert ObjectModel.box((0.05, 0.05, 0.05), mass=0.2).mass == 0.2
    assert ObjectModel.box((0.05, 0.05, 0.05), density=800.0).mass == pytest.approx(800 * volume)
    default = ObjectModel.box((0.05, 0.05, 0.05))
    assert default.mass == pytest.approx(DEFAULT_DENSITY * volume)
    assert "default density" in default.source
    with pytest.raises(ConfigError, match="not both"):
        ObjectModel.box((0.05, 0.05, 0.05), mass=0.2, density=800.0)


@pytest.mark.parametrize(
    "make",
    [
        lambda: ObjectModel.box((0.05, -0.05, 0.05)),
        lambda: ObjectModel.box((0.05, 0.05)),
        lambda: ObjectModel.sphere(0.0),
        lambda: ObjectModel.sphere(float("nan")),
        lambda: ObjectModel.cylinder(0.03, -0.1),
        lambda: ObjectModel.capsule(0.02, 0.08, mass=-1.0),
        lambda: ObjectModel.sphere(0.04, friction=-0.1),
        lambda: ObjectModel.sphere(0.04, density=0.0),
        lambda: ObjectModel.sphere(5.0),  # 10 m across: millimetres by mistake
        lambda: ObjectModel.sphere(0.001),  # 2 mm across
        lambda: ObjectModel.sphere(0.04, sdf_spacing=0.0),
    ],
)
def test_bad_primitive_arguments_raise(make) -> None:
    with pytest.raises(ConfigError):
        make()


def test_model_validates_its_fields() -> None:
    good = ObjectModel.box((0.05, 0.05, 0.05), mass=0.1)
    fields = dict(
        name="x",
        mesh=good.mesh,
        mass=0.1,
        friction=0.7,
        com=np.zeros(3),
        inertia=good.inertia,
        source="test",
    )
    ObjectModel(**fields)
    for bad in (
        {"mass": 0.0},
        {"com": np.zeros(2)},
        {"inertia": np.array([[1.0, 0.1, 0], [0, 1.0, 0], [0, 0, 1.0]]) * 1e-4},  # not symmetric
        {"inertia": -np.eye(3)},  # not positive
        {"kind": "torus"},
    ):
        with pytest.raises(ConfigError):
            ObjectModel(**{**fields, **bad})
    with pytest.raises(AssetError):
        ObjectModel(**{**fields, "mesh": trimesh.Trimesh()})
    with pytest.raises(ValueError):
        good.com[0] = 1.0  # read-only


# --- primitive specs ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("box:0.05x0.05x0.1", ("box", [0.05, 0.05, 0.1])),
        ("sphere:0.04", ("sphere", [0.04])),
        ("cylinder:0.03x0.12", ("cylinder", [0.03, 0.12])),
        ("capsule:0.02x0.08", ("capsule", [0.02, 0.08])),
        ("Box: 0.05 x 0.06 x 0.1", ("box", [0.05, 0.06, 0.1])),
        ("006_mustard_bottle", None),
        ("mesh.stl", None),
    ],
)
def test_parse_primitive_spec(spec: str, expected) -> None:
    assert parse_primitive_spec(spec) == expected


@pytest.mark.parametrize(
    "spec",
    [
        "box:0.05x0.05",
        "sphere:",
        "sphere:-0.04",
        "cylinder:abc",
        "capsule:0.02x0.08x1",
        "box:1x1xnan",
    ],
)
def test_bad_primitive_spec_raises(spec: str) -> None:
    with pytest.raises(ConfigError, match="primitive spec"):
        parse_primitive_spec(spec)
    with pytest.raises(ConfigError, match="primitive spec"):
        load_object(spec)


def test_load_object_primitive_with_overrides() -> None:
    obj = load_object("cylinder:0.03x0.12", mass=0.25, friction=0.5)
    assert (obj.kind, obj.mass, obj.friction) == ("cylinder", 0.25, 0.5)
    assert obj.dimensions == {"radius": 0.03, "height": 0.12}
    box = load_object("box:0.05x0.05x0.1", name="brick")
    assert box.name == "brick" and box.dimensions["size"] == (0.05, 0.05, 0.1)
    with pytest.raises(ConfigError, match="unknown options"):
        load_object("sphere:0.04", colour="red")


# --- mesh files -----------------------------------------------------------------------------------
def test_from_mesh_mass_properties_follow_the_mesh(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=(0.04, 0.06, 0.08))
    box.apply_translation([0.1, -0.02, 0.03])
    path = write_mesh(box, tmp_path / "brick.stl")
    obj = ObjectModel.from_mesh(path, density=700.0)
    assert obj.name == "brick" and obj.kind == "mesh" and obj.dimensions == {}
    assert obj.mass == pytest.approx(700.0 * 0.04 * 0.06 * 0.08, rel=1e-6)
    np.testing.assert_allclose(obj.com, [0.1, -0.02, 0.03], atol=1e-8)
    x2, y2, z2 = 0.04**2, 0.06**2, 0.08**2
    np.testing.assert_allclose(
        obj.inertia, obj.mass / 12 * np.diag([y2 + z2, x2 + z2, x2 + y2]), rtol=1e-6, atol=1e-12
    )  # STL stores float32 vertices
    assert str(path) in obj.source and "700" in obj.source
    assert load_object(str(path), mass=0.1).mass == 0.1


def test_missing_file_raises_asset_error_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere" / "ghost.stl"
    with pytest.raises(AssetError, match="ghost.stl"):
        ObjectModel.from_mesh(missing)
    with pytest.raises(AssetError, match="ghost.stl"):
        load_object(str(missing))


def test_unreadable_file_raises_asset_error(tmp_path: Path) -> None:
    path = tmp_path / "junk.stl"
    path.write_bytes(b"\x00\x01 not a mesh")
    with pytest.raises(AssetError, match="junk.stl"):
        ObjectModel.from_mesh(path)


def test_a_nan_vertex_is_named_not_reported_as_holes(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=[0.05, 0.05, 0.05])
    vertices = box.vertices.copy()
    vertices[3, 1] = np.nan
    path = tmp_path / "nan_box.obj"
    path.write_text(trimesh.Trimesh(vertices, box.faces, process=False).export(file_type="obj"))
    with pytest.raises(AssetError, match="1 vertices with NaN or infinite coordinates.*index 3"):
        ObjectModel.from_mesh(path, repair=True)


def test_a_huge_mesh_is_refused_with_the_fix(tmp_path: Path, monkeypatch) -> None:
    import wholehand.models.mesh_repair as mesh_repair

    path = tmp_path / "scan.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=0.05).export(path)  # 1280 faces
    monkeypatch.setattr(mesh_repair, "MAX_MESH_FACES", 1000)
    with pytest.raises(AssetError, match="has 1280 triangles, more than the 1000.*decimate"):
        ObjectModel.from_mesh(path)


def test_non_watertight_mesh_needs_explicit_repair(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    path = write_mesh(trimesh.Trimesh(box.vertices, box.faces[1:]), tmp_path / "open_box.stl")
    with pytest.raises(AssetError, match="watertight") as info:
        ObjectModel.from_mesh(path)
    assert "repair=True" in str(info.value) and "boundary edges" in str(info.value)
    fixed = ObjectModel.from_mesh(path, repair=True)
    assert fixed.mesh.is_watertight
    assert fixed.volume == pytest.approx(0.05**3, rel=1e-6)
    assert "repaired" in fixed.source and "cm^3" in fixed.source


@pytest.mark.parametrize("shape", ["cup_shell", "sheet"])
def test_an_open_surface_is_not_made_a_solid_of_invented_volume(shape: str) -> None:
    """A single-layer cup without a lid, or a flat sheet, closes only by the voxel remesh, which
    gives it walls a voxel thick: a volume the surface never enclosed. Refused, with the
    volumes and the bound."""
    if shape == "cup_shell":
        cylinder = trimesh.creation.cylinder(radius=0.02, height=0.04, sections=64)
        mesh = trimesh.Trimesh(
            cylinder.vertices, cylinder.faces[cylinder.triangles_center[:, 2] < 0.0199]
        )
    else:
        square = [[0, 0, 0], [0.05, 0, 0], [0.05, 0.05, 0], [0, 0.05, 0]]
        mesh = trimesh.Trimesh(vertices=square, faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.raises(AssetError) as err:
        repair_mesh(mesh, shape)
    message = str(err.value)
    assert f"mesh of {shape!r} cannot be closed without changing its volume" in message
    assert "voxel remesh" in message
    assert "more than the 10 % a repair may change" in message and "cm^3" in message


def test_inconsistent_winding_needs_repair() -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    flipped = trimesh.Trimesh(box.vertices, faces, process=False)
    assert flipped.is_watertight and not flipped.is_winding_consistent
    with pytest.raises(AssetError, match="winding inconsistent"):
        ObjectModel.from_trimesh(flipped, "one_face_flipped")
    fixed = ObjectModel.from_trimesh(flipped, "one_face_flipped", repair=True)
    assert fixed.mesh.is_winding_consistent and fixed.volume == pytest.approx(0.05**3)
    with pytest.raises(AssetError, match="winding"):
        SignedDistanceGrid.from_mesh(flipped, use_cache=False)


def test_coincident_faces_are_removed() -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    faces = np.vstack([box.faces, box.faces[:1], box.faces[1:2, ::-1], box.faces[1:2]])
    bad = trimesh.Trimesh(box.vertices, faces, process=False)
    assert not bad.is_watertight
    fixed, note = repair_mesh(bad)
    assert fixed.is_watertight and len(fixed.faces) == 12
    assert fixed.volume == pytest.approx(0.05**3)


def test_inside_out_mesh_is_inverted(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    obj = ObjectModel.from_trimesh(trimesh.Trimesh(box.vertices, box.faces[:, ::-1]), "flipped")
    assert obj.volume > 0.0 and "inverted" in obj.source


@pytest.mark.parametrize(("scale", "word"), [(1000.0, "millimetres"), (0.05, "unit")])
def test_implausible_size_raises_config_error(tmp_path: Path, scale: float, word: str) -> None:
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.1))
    box.apply_scale(scale)
    path = write_mesh(box, tmp_path / "scaled.stl")
    with pytest.raises(ConfigError, match=word):
        ObjectModel.from_mesh(path)


# --- YCB registry ---------------------------------------------------------------------------------
def test_available_objects_are_the_78_ycb_meshes() -> None:
    names = available_objects()
    assert len(names) == 78 and names == sorted(names)
    assert set(PAPER_OBJECTS) <= set(names)
    assert all((ycb_mesh_dir() / f"{n}.stl").is_file() for n in names)


def test_registry_entries_are_ycb_names_and_repair_flags_are_exact() -> None:
    """The toml's repair flags are exactly the non-watertight meshes (loads 78 STLs, ~3 s)."""
    registry = ycb_registry()
    assert set(registry) <= set(available_objects())
    open_meshes = {
        n
        for n in available_objects()
        if not trimesh.load(ycb_mesh_dir() / f"{n}.stl", force="mesh").is_watertight
    }
    flagged = {n for n, entry in registry.items() if entry.get("repair", False)}
    assert flagged == open_meshes
    assert "006_mustard_bottle" in open_meshes
    for entry in registry.values():
        assert not ("mass" in entry and "density" in entry)
        if "mass" in entry or "density" in entry:
            assert entry.get("source"), "every registered mass or density cites its source"


def test_unknown_name_suggests_close_matches() -> None:
    with pytest.raises(ConfigError) as info:
        load_object("006_mustard_botle")
    message = str(info.value)
    assert "006_mustard_bottle" in message and "available_objects" in message
    with pytest.raises(ConfigError, match="unknown object"):
        load_object("teapot")


def test_mustard_mesh_is_not_watertight_and_needs_repair() -> None:
    path = ycb_mesh_dir() / "006_mustard_bottle.stl"
    with pytest.raises(AssetError, match="watertight") as info:
        ObjectModel.from_mesh(path)
    assert "repair" in str(info.value)


def test_registered_object_is_repaired_on_load(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="wholehand.models.object_catalogue"):
        obj = load_object("006_mustard_bottle")
    assert "repairing" in caplog.text
    assert obj.mesh.is_watertight and "repaired" in obj.source and "(+0.00 %)" in obj.source
    assert obj.mass == 0.603 and obj.friction == 0.7 and "Calli" in obj.source
    # Overrides take precedence over the registry.
    assert load_object("006_mustard_bottle", mass=0.5).mass == 0.5
    heavy = load_object("006_mustard_bottle", density=1000.0)
    assert heavy.mass == pytest.approx(1000.0 * heavy.volume)
    with pytest.raises(AssetError, match="watertight"):
        load_object("006_mustard_bottle", repair=False)


def test_unregistered_ycb_object_uses_default_density() -> None:
    name = next(n for n in available_objects() if n not in ycb_registry())
    obj = load_object(name)
    assert obj.mass == pytest.approx(DEFAULT_DENSITY * obj.volume)
    assert "default density" in obj.source


@pytest.fixture(scope="module")
def paper_objects() -> dict[str, ObjectModel]:
    return {name: load_object(name) for name in PAPER_OBJECTS}


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_paper_objects_load_with_mass_and_a_valid_sdf(
    paper_objects: dict[str, ObjectModel], name: str
) -> None:
    obj = paper_objects[name]
    assert obj.mass > 0.0 and obj.friction == 0.7 and obj.mesh.is_watertight
    assert 0.005 < float(np.max(obj.extents)) < 0.3
    assert np.all(np.linalg.eigvalsh(obj.inertia) > 0.0)
    grid = obj.sdf
    assert isinstance(grid, SignedDistanceGrid) and obj.sdf is grid  # built once
    lo, hi = grid.bounds
    assert np.all(lo <= obj.mesh.bounds[0] - 0.03 + 1e-9)
    assert np.all(hi >= obj.mesh.bounds[1] + 0.03 - 1e-9)
    # Zero on the surface; off it, the exact signed distance to within the interpolation error.
    rng = np.random.default_rng(1)
    points, face = trimesh.sample.sample_surface(obj.mesh, 400, seed=1)
    normals = obj.mesh.face_normals[face]
    np.testing.assert_allclose(grid.query(points), 0.0, atol=1e-3)
    near = points + rng.uniform(-0.006, 0.006, size=(400, 1)) * normals
    dist = MeshDistance(np.asarray(obj.mesh.vertices), obj.mesh.faces, 0.001)
    err = np.abs(grid.query(near) - dist.signed_distance(near).distance)
    assert err.max() < grid.spacing and np.median(err) < 1e-4
    _, g = grid.query_with_gradient(points + 0.002 * normals)
    assert np.median(np.sum(g * normals, axis=1)) > 0.95  # gradients are outward normals
    assert np.all(grid.query(grid.bounds[:1] - 0.01) > 0.03)  # far outside: positive
    summary = json.loads(json.dumps(obj.summary()))
    assert summary["name"] == name and summary["mass_kg"] == obj.mass


def test_sdf_spacing_and_padding_are_used() -> None:
    obj = load_object("sphere:0.03", sdf_spacing=0.004, sdf_padding=0.01)
    assert obj.sdf.spacing == 0.004
    lo, hi = obj.sdf.bounds
    assert np.all(lo <= -0.04 + 1e-9) and np.all(lo > -0.04 - 0.004)
    assert np.all(hi >= 0.04 - 1e-9) and np.all(hi < 0.04 + 0.004)


def test_module_constants_are_consistent() -> None:
    assert objects.DEFAULT_FRICTION == 0.7
    assert objects.SPHERE_SUBDIVISIONS >= 4 and objects.CYLINDER_SECTIONS >= 128
