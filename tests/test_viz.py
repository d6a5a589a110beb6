"""Visualisation: colour scales, arrow filtering, plots, the meshcat scene and a real browser.

The browser test writes the standalone HTML animation of a short synthetic record, screenshots
it with headless Chromium and checks pixels: the hand is drawn, and the force arrows' colours
appear. It skips only when no Chromium is installed or it cannot start.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import umsgpack

from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop.record import RunRecord
from wholehand.models.hand import load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.viz.arrows import force_arrows
from wholehand.viz.colours import ColourScale, distance_rgb, distance_to_nearest_contact
from wholehand.viz.plots import phase_boundaries, plot_run
from wholehand.viz.recording import RecordingWindow
from wholehand.viz.replay import build_animation, frame_cycles, write_html
from wholehand.viz.scene import HIDDEN_SCALE, NodePose, SceneViewer

FORCES_N = (0.3, 1.0, 2.5, 4.5)
"""Synthetic contact force magnitudes; the first is below the 0.5 N arrow threshold."""


@pytest.fixture(scope="module")
def hand():
    return load_hand("allegro_right")


@pytest.fixture(scope="module")
def obj():
    return load_object("077_rubiks_cube")


@pytest.fixture(scope="module")
def record(hand, obj) -> RunRecord:
    """12 cycles over two phases holding a stored grasp; one contact per fingertip with forces
    FORCES_N pointing at the object's centre."""
    grasp = load_grasps(hand.name, obj.name)[0]
    q = grasp.q_array(hand)
    wMo = grasp.object_pose(hand.wMb)
    kin = HandKinematics(hand)
    kin.update(q, hand.wMb)
    s = hand.samples
    p_world = kin.transform_points(s.p_joint, s.joint)
    centre = wMo[:3, 3]
    tips = np.flatnonzero(hand.link_fingertip)[: len(FORCES_N)]
    rows = [
        np.flatnonzero(s.link == k)[
            np.argmin(np.linalg.norm(p_world[s.link == k] - centre, axis=1))
        ]
        for k in tips
    ]
    contact_p = p_world[rows]
    direction = centre - contact_p
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    contact_f = direction * np.asarray(FORCES_N)[: len(rows), None]
    rec = RunRecord(
        meta={"spec": {"hand": hand.name, "object": obj.name, "grasp": 0}},
        phases=["settle", "load +x"],
    )
    for i in range(12):
        rec.append(
            t=0.05 * i,
            stamp_object=0.05 * i,
            phase=int(i >= 6),
            stage="regulate",
            n_contacts=len(rows),
            residual_wrench=np.full(6, 1e-3 * i),
            tau=np.linspace(-0.1, 0.1, hand.nv),
            qp_time=1e-4,
            estimate_time=1e-4,
            cycle_time=5e-4,
            status="ok",
            held=True,
            p_object=wMo[:3, 3].copy(),
            r_object=pin.log3(wMo[:3, :3]),
            q=q.copy(),
            contact_p=contact_p,
            contact_n=-direction,
            contact_f=contact_f,
            contact_link=tips.astype(np.intp),
        )
    return rec


# --- colour mapping and arrow filtering -----------------------------------------------------------
def test_colour_scale_bins_and_ends():
    scale = ColourScale(f_min=0.5, f_max=4.5, n_bins=4)
    np.testing.assert_array_equal(
        scale.bin([0.0, 0.5, 1.49, 1.5, 4.49, 4.5, 100.0]), [0, 0, 0, 1, 3, 3, 3]
    )
    np.testing.assert_allclose(scale.bin_edges(), [0.5, 1.5, 2.5, 3.5, 4.5])
    rgb = scale.rgb([0.5, 4.5])
    assert rgb.shape == (2, 3) and np.all((0 <= rgb) & (rgb <= 1))
    assert not np.allclose(rgb[0], rgb[1])
    assert len({tuple(c) for c in scale.bin_rgb().round(6)}) == 4  # distinct colours


def test_colour_scale_for_forces_and_invalid():
    assert ColourScale.for_forces([0.7, 3.2]).f_max == 4.0
    assert ColourScale.for_forces([]).f_max == 1.5
    for bad in [dict(f_min=1.0, f_max=1.0), dict(f_min=-1.0), dict(f_max=np.nan), dict(n_bins=0)]:
        with pytest.raises(ConfigError, match="ColourScale"):
            ColourScale(**bad)


def test_legend_png_is_a_png():
    png = ColourScale().legend_png()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000


def test_force_arrows_keep_forces_of_at_least_half_a_newton():
    p = np.arange(15.0).reshape(5, 3)
    f = np.array([[0, 0, 0.49], [0, 0.5, 0], [3, 4, 0], [0, 0, -0.2], [-2, 0, 0]], dtype=float)
    arrows = force_arrows(p, f)
    np.testing.assert_array_equal(arrows.row, [1, 2, 4])
    np.testing.assert_allclose(arrows.magnitude, [0.5, 5.0, 2.0])
    np.testing.assert_allclose(arrows.tip, p[[1, 2, 4]])
    np.testing.assert_allclose(np.linalg.norm(arrows.direction, axis=1), 1.0)
    np.testing.assert_allclose(arrows.direction[1], [0.6, 0.8, 0.0])
    assert np.all(arrows.length > 0)
    assert len(force_arrows(np.zeros((0, 3)), np.zeros((0, 3))).row) == 0
    with pytest.raises(ConfigError, match="force_arrows"):
        force_arrows(np.zeros((2, 3)), np.zeros((3, 3)))


def test_distance_to_nearest_contact_is_analytic():
    points = np.array([[0.0, 0, 0], [0.03, 0, 0], [0.0, 0.1, 0]])
    contacts = np.array([[0.0, 0, 0], [0.04, 0, 0]])
    np.testing.assert_allclose(distance_to_nearest_contact(points, contacts), [0.0, 0.01, 0.1])
    assert np.all(np.isinf(distance_to_nearest_contact(points, np.zeros((0, 3)))))
    rgb = distance_rgb(np.array([0.0, 0.05, 1.0, np.inf]))
    np.testing.assert_allclose(rgb[1], rgb[2])  # clipped at the far end
    np.testing.assert_allclose(rgb[2], rgb[3])  # no contact: far colour
    assert not np.allclose(rgb[0], rgb[1])


def test_node_pose_round_trip():
    M = np.eye(4)
    M[:3, :3] = pin.exp3(np.array([0.3, -0.2, 0.5]))
    M[:3, 3] = [0.1, 0.2, 0.3]
    pose = NodePose.from_matrix(M, (1.0, 0.04, 1.0))
    np.testing.assert_allclose(pose.matrix(), M @ np.diag([1.0, 0.04, 1.0, 1.0]), atol=1e-12)


# --- scene and replay -----------------------------------------------------------------------------
def test_scene_poses_draw_only_arrows_above_threshold(hand, obj, record):
    viewer = SceneViewer.offline(hand, obj, colour_scale=ColourScale(f_max=5.0))
    c = record.contacts_at(0)
    wMo = np.eye(4)
    poses = viewer.poses(record.rows["q"][0], wMo, c["contact_p"], c["contact_f"])
    shown = {p: v for p, v in poses.items() if "/forces/" in p and v.scale[0] > HIDDEN_SCALE}
    assert len(shown) == sum(f >= 0.5 for f in FORCES_N)
    spheres = [v for p, v in poses.items() if "/contacts/" in p and v.scale[0] > HIDDEN_SCALE]
    assert len(spheres) == len(FORCES_N)
    # every arrow ends at its contact point and its length follows the force
    tips = [np.asarray(v.position) + v.matrix()[:3, 1] for v in shown.values()]
    for tip in tips:
        assert np.min(np.linalg.norm(c["contact_p"] - tip, axis=1)) < 1e-9
    # the arrow's colour bin is the path's bin
    bins = ColourScale(f_max=5.0).bin([f for f in FORCES_N if f >= 0.5])
    assert sorted(int(p.split("/")[-2]) for p in shown) == sorted(bins.tolist())
    # the hand joints sit where forward kinematics puts them
    kin = HandKinematics(hand)
    kin.update(record.rows["q"][0], hand.wMb)
    j = int(hand.link_joint[-1])
    np.testing.assert_allclose(
        poses[f"wholehand/hand/{hand.model.names[j]}"].position, kin.bp_j[j], atol=1e-9
    )


def test_distance_colour_toggle(hand, obj, record):
    viewer = SceneViewer.offline(hand, obj)
    c = record.contacts_at(0)
    viewer.update(record.rows["q"][0], np.eye(4), c["contact_p"], c["contact_f"])
    viewer.set_distance_colours(True)
    d = viewer.colour_distances(c["contact_p"])
    assert d.shape == (len(hand.samples),) and np.isclose(d.min(), 0.0, atol=1e-9)
    viewer.set_distance_colours(False)
    assert viewer.distance_colours is False


def test_animation_and_html_embed_the_viewer(tmp_path, hand, obj, record):
    np.testing.assert_array_equal(frame_cycles(record, fps=10.0), [0, 2, 4, 6, 8, 10, 11])
    viewer = SceneViewer.offline(hand, obj)
    animation = build_animation(viewer, record, fps=10.0)
    assert len(animation.clips) > len(hand.link_names)
    out = write_html(record, tmp_path / "run.html", hand, obj, distance_colours=True)
    html = out.read_text()
    assert "MeshCat.Viewer" in html and "handle_command_bytearray" in html
    assert "<script src=" not in html and "http://" not in html.split("<script>")[0]
    assert "wholehand-overlay" in html and isinstance(viewer.vis.window, RecordingWindow)


def test_plot_written(tmp_path, record):
    assert [name for _, name in phase_boundaries(record)] == ["settle", "load +x"]
    out = plot_run(record, tmp_path / "plot.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


def test_cli_view_writes_files(tmp_path, record):
    from wholehand.cli.main import main

    path = record.save(tmp_path / "rec.npz")
    rc = main(
        ["view", str(path), "--html", str(tmp_path / "v.html"), "--plot", str(tmp_path / "v.png")]
    )
    assert (
        rc == 0
        and (tmp_path / "v.html").stat().st_size > 100_000
        and (tmp_path / "v.png").is_file()
    )
    assert main(["view", str(tmp_path / "missing.npz"), "--plot", str(tmp_path / "x.png")]) == 2


# --- a real browser -------------------------------------------------------------------------------
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--enable-unsafe-swiftshader",
)
WINDOW = (800, 600)


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if path := shutil.which(name):
            return path
    return None


def screenshot(html: Path, out: Path, profile: Path) -> np.ndarray:
    """Screenshot of a page in headless Chromium as (H, W, 3) uint8; skips if it cannot run."""
    from PIL import Image

    exe = _chromium()
    if exe is None:
        pytest.skip("Chromium is not installed (apt-get install -y chromium; see .ci/chromium)")
    cmd = [
        exe,
        *CHROMIUM_FLAGS,
        f"--user-data-dir={profile}",
        f"--screenshot={out}",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
        "--virtual-time-budget=5000",
        html.resolve().as_uri(),
    ]
    try:
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=45)
    except (OSError, subprocess.TimeoutExpired) as err:
        pytest.skip(f"Chromium cannot start: {err}")
    if not out.is_file():
        pytest.skip(f"Chromium wrote no screenshot (exit {run.returncode}): {run.stderr[-500:]}")
    return np.asarray(Image.open(out).convert("RGB"))


def test_html_animation_renders_in_chromium(tmp_path, hand, obj, record):
    html = write_html(record, tmp_path / "run.html", hand, obj)
    img = screenshot(html, tmp_path / "shot.png", tmp_path / "profile").astype(int)
    assert img.shape[:2] == (WINDOW[1], WINDOW[0])
    scene = np.ones(img.shape[:2], dtype=bool)
    scene[:30, :] = False  # meshcat's "Open Controls" bar
    scene[-300:, :170] = False  # the colour-bar overlay
    background = np.all(img > 245, axis=2)
    assert background[scene].mean() > 0.5, "the page is not mostly background: scene not set up"
    # The hand: dark grey (URDF colour, lit) pixels.
    grey = (img.max(axis=2) - img.min(axis=2) < 20) & (img.max(axis=2) < 120)
    assert (grey & scene).sum() > 300, "no hand pixels in the screenshot"
    # The arrows: the exact colours of the drawn bins (unlit material).
    forces = [f for f in FORCES_N if f >= 0.5]
    scale = ColourScale.for_forces(FORCES_N)
    found = 0
    for rgb in {tuple(c) for c in np.round(255 * scale.rgb(forces)).astype(int)}:
        close = np.all(np.abs(img - np.asarray(rgb)) <= 12, axis=2) & scene
        assert close.sum() > 5, f"force-arrow colour {rgb} not in the screenshot"
        found += close.sum()
    assert found > 40


def test_live_page_renders_in_chromium(tmp_path, hand, obj, record):
    viewer = SceneViewer.live(hand, obj)
    try:
        i = int(np.argmax(record.arrays()["n_contacts"]))
        a, c = record.arrays(), record.contacts_at(i)
        wMo = np.eye(4)
        wMo[:3, :3], wMo[:3, 3] = pin.exp3(a["r_object"][i]), a["p_object"][i]
        viewer.set_camera(wMo[:3, 3])
        viewer.update(a["q"][i], wMo, c["contact_p"], c["contact_f"], hand.wMb)
        exe = _chromium()
        if exe is None:
            pytest.skip("Chromium is not installed (apt-get install -y chromium; see .ci/chromium)")
        from PIL import Image

        # The meshes reach the page over the viewer's websocket in real time, which Chromium's
        # virtual time does not wait for: on a busy machine a screenshot can come first, so up
        # to three page loads are tried.
        hand_pixels = []
        for attempt in range(3):
            out = tmp_path / f"live{attempt}.png"
            cmd = [
                exe,
                *CHROMIUM_FLAGS,
                f"--user-data-dir={tmp_path / f'profile{attempt}'}",
                f"--screenshot={out}",
                f"--window-size={WINDOW[0]},{WINDOW[1]}",
                "--virtual-time-budget=8000",
                viewer.url,
            ]
            try:
                subprocess.run(cmd, capture_output=True, text=True, timeout=60)
            except (OSError, subprocess.TimeoutExpired) as err:
                pytest.skip(f"Chromium cannot start: {err}")
            if not out.is_file():
                pytest.skip("Chromium wrote no screenshot of the live page")
            img = np.asarray(Image.open(out).convert("RGB")).astype(int)
            scene = np.ones(img.shape[:2], dtype=bool)
            scene[:30, :] = False
            grey = (img.max(axis=2) - img.min(axis=2) < 20) & (img.max(axis=2) < 120)
            hand_pixels.append(int((grey & scene).sum()))
            if hand_pixels[-1] > 300:
                break
        assert hand_pixels[-1] > 300, f"no hand pixels on the live page: {hand_pixels}"
    finally:
        viewer.vis.window.server_proc.kill()


def test_a_table_is_drawn_where_it_stands(hand, obj):
    from meshcat.servers.tree import find_node

    from wholehand.backends.table import Table

    viewer = SceneViewer.offline(hand, obj)
    viewer.draw_table(Table(top=0.1, centre=(0.2, -0.1), thickness=0.04))
    node = find_node(viewer.vis.window.tree, ["meshcat", "wholehand", "table"])
    assert node.object is not None
    matrix = np.asarray(umsgpack.unpackb(node.transform)["matrix"], dtype=float)
    # meshcat stores the 4x4 transform column by column; the box's centre is 2 cm below the top
    np.testing.assert_allclose(matrix.reshape(4, 4).T[:3, 3], [0.2, -0.1, 0.08], atol=1e-6)


def test_the_camera_frames_every_point_of_the_scene():
    from wholehand.viz.scene import CAMERA_FOV_DEG, framing

    rng = np.random.default_rng(0)
    points = rng.uniform(-0.4, 0.4, size=(200, 3)) + [0.5, 0.0, 0.3]
    target, offset = framing(points)
    camera = target + np.asarray(offset)
    axis = (target - camera) / np.linalg.norm(target - camera)
    rays = points - camera
    angles = np.degrees(np.arccos(rays @ axis / np.linalg.norm(rays, axis=1)))
    assert angles.max() < 0.5 * CAMERA_FOV_DEG  # every point within the vertical field of view
    assert angles.max() > 0.3 * CAMERA_FOV_DEG  # and the scene fills a good part of it
    near, _ = framing([[1.0, 2.0, 3.0]])  # a single point: a small sphere about it
    np.testing.assert_allclose(near, [1.0, 2.0, 3.0])


def test_a_reach_recording_shows_hand_object_and_table_in_chromium(tmp_path, hand, obj, record):
    """A reach's start: the hand between the object and where a camera aimed at the object
    alone would stand (as the arm's start put it in `wholehand reach`), on a table. The camera
    frames them: the palm must not fill the page, nor the object be a sliver."""
    from wholehand.backends.table import Table

    n = len(record.rows["t"])
    reach = RunRecord(meta={**record.meta, "table": Table(top=-0.1, size=(0.8, 0.8)).__dict__})
    reach.phases = ["run"]
    start = hand.wMb.copy()
    start[:3, 3] = record.rows["p_object"][0] + [0.07, 0.1, 0.12]
    for i in range(n):
        base = start
        values = {key: record.rows[key][i] for key in RunRecord.FIELDS if key in record.rows}
        values.update(p_base=base[:3, 3].copy(), r_base=pin.log3(base[:3, :3]))
        reach.append(**values, **record.contacts_at(i))
    html = write_html(reach, tmp_path / "reach.html", hand, obj)
    img = screenshot(html, tmp_path / "shot.png", tmp_path / "profile").astype(int)
    scene = np.ones(img.shape[:2], dtype=bool)
    scene[:30, :] = False
    scene[-300:, :170] = False
    grey = (img.max(axis=2) - img.min(axis=2) < 20) & (img.max(axis=2) < 120) & scene
    teal = (img[..., 1] > img[..., 0] + 40) & (img[..., 2] > img[..., 0] + 30) & scene
    brown = (img[..., 0] > img[..., 2] + 25) & (img[..., 1] > img[..., 2] + 10) & scene
    assert 300 < grey.sum() < 0.4 * scene.sum(), f"hand pixels: {grey.sum()}"
    assert teal.sum() > 300, f"object pixels: {teal.sum()}"
    assert brown.sum() > 1000, f"table pixels: {brown.sum()}"
    rows, cols = np.nonzero(grey | teal)
    h, w = img.shape[:2]
    assert 0.1 * h < rows.mean() < 0.9 * h and 0.1 * w < cols.mean() < 0.9 * w


def test_view_of_a_record_naming_an_unknown_hand_names_the_file(tmp_path, record, capsys):
    import copy

    from wholehand.cli.main import main

    other = copy.copy(record)  # the fixture is shared: a copy names the unknown hand
    other.meta = {**record.meta, "spec": {**record.meta.get("spec", {}), "hand": "no_such_hand"}}
    path = other.save(tmp_path / "rec.npz")
    assert main(["view", str(path), "--html", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert f"{path}: no hand named 'no_such_hand'" in err and "Traceback" not in err
