"""Metric scale from printed targets found in the photos (sfm.aruco, sfm.chessboard): the synthetic
scene with two ArUco markers and a chessboard (marker_scene.py) through the sparse pipeline, with the
truth known (the scene's unit read as the metre); the board's corner order and false boards on
projected corners; the warning when no marker is found."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from marker_scene import INNER, MARKER_SIDE, SQUARE, board_corners, marker_corners, render_marker_scene

import recon
from recon.config import ConfigError
from recon.geometry.transforms import umeyama
from recon.report import Sources, build_report
from recon.sparse.control import BarEnd, ScaleBar
from recon.sparse.georeference import place
from recon.sparse.markers import ArucoMarkers, Chessboard, board_orders, board_targets, marker_targets, search
from recon.synth import load_scene

REPO = Path(__file__).resolve().parents[2]
SPARSE_TEST = REPO / "tests" / "sparse_test.yaml"
ARUCO = {"dictionary": "DICT_4X4_50", "size": MARKER_SIDE}
BOARD = {"columns": INNER[0], "rows": INNER[1], "square": SQUARE}


@pytest.fixture(scope="module")
def marker_scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("markers") / "scene"
    render_marker_scene(out)
    return out


@pytest.fixture(scope="module")
def marker_workspace(marker_scene, tmp_path_factory) -> Path:
    """The sparse pipeline with both kinds of target described: the markers set the scale, the board
    checks it."""
    ws = tmp_path_factory.mktemp("markers_ws") / "ws"
    recon.run(SPARSE_TEST, images=str(marker_scene / "images"), workspace=str(ws), sfm={"aruco": ARUCO, "chessboard": BOARD})
    return ws


def _scale_error(model, scene: Path) -> float:
    """How far the model's scale is from the truth's (relative): the similarity from its camera
    centres to the true ones."""
    true = {n: c.center for n, c in load_scene(scene).cameras().items()}
    names = sorted(img.name for img in model.images.values())
    found = np.array([model.find_image_with_name(n).projection_center() for n in names])
    return 1 / umeyama(found, np.array([true[n] for n in names])).s - 1


def _shrunk(workspace: Path, factor: float = 0.37):
    """The workspace's model, scaled by ``factor``: out of metres again."""
    model = pycolmap.Reconstruction(str(workspace / "sparse" / "0"))
    model.transform(pycolmap.Sim3d(factor, pycolmap.Rotation3d(), np.zeros(3)))
    return model


def test_aruco_markers_put_the_workspace_in_metres(marker_scene, marker_workspace):
    georef = json.loads((marker_workspace / "georeference.json").read_text())
    assert georef["scale_source"] == "ArUco markers" and not georef["georeferenced"]
    aruco, board = georef["markers"]
    assert aruco["used"] and aruco["set_scale"] and aruco["photos_searched"] == 16
    assert [t["name"] for t in aruco["targets"]] == ["ArUco 3", "ArUco 7"] and aruco["edges"] == 8
    error = _scale_error(pycolmap.Reconstruction(str(marker_workspace / "sparse" / "0")), marker_scene)
    print(f"ArUco markers: model scale {100 * error:+.3f} % from the truth, stated +-{100 * aruco['scale_relative_std']:.3f} "
          f"%; targets {[(t['name'], len(t['photos']), round(t['residual_m'], 5)) for t in aruco['targets']]}; the "
          f"board measures x{board['scale']:.5f} ({len(board['targets'][0]['photos'])} photos)")
    assert abs(error) < 0.01
    for target in aruco["targets"]:
        assert len(target["photos"]) >= 2 and target["length_m"] == [MARKER_SIDE] * 4
        assert target["residual_m"] < 0.01 * MARKER_SIDE and target["reprojection_px"] < 2.0
        assert np.allclose(target["model_length_m"], MARKER_SIDE, rtol=0.02)
    assert georef["model_scale"]["scale"] == aruco["scale"]
    # the board, described too, only checks the scale the markers set: it agrees within 1 %
    assert board["used"] and not board["set_scale"] and abs(board["scale"] - 1) < 0.01
    log = (marker_workspace / ".recon" / "recon.log").read_text()
    assert "sfm: ArUco markers (DICT_4X4_50 markers of side 0.39 m): 2 target(s), 8 edges" in log
    assert "they set the scale" in log and "a check of the scale" in log
    # the report says where the scale came from, and lists the targets
    page = build_report(Sources(model=marker_workspace / "sparse" / "0",
                                georeference=marker_workspace / "georeference.json"), title="t").html
    section = re.search(r'<section id="georeference">(.*?)</section>', page, re.S).group(1)
    assert "<b>ArUco markers</b><span>scale from</span>" in section
    assert "<td>ArUco 7</td>" in section and "<h3>Chessboard</h3>" in section and "a check of the scale" in section


def test_chessboard_alone_sets_the_scale_with_each_photos_corners_in_one_order(marker_scene, marker_workspace):
    """The board found in the rendered photos: the detector starts some photos' corners from the other
    end, and assembles boards from the partly hidden one in others; the kept photos' corners all
    match the true corners in one order, and the scale is the truth's."""
    model = _shrunk(marker_workspace)
    found = search(model, marker_workspace / "images", Chessboard(*INNER, SQUARE))
    (target,) = found.targets
    photos = [name for name, _, _ in target.corners[0]]
    assert found.photos_with_detections > len(photos) >= 5
    cameras = load_scene(marker_scene).cameras()
    true = {name: cameras[name].project(board_corners())[0] - 0.5 for name in photos}
    seen = {name: np.array([[x, y] for corner in target.corners for n, x, y in corner if n == name]) for name in photos}
    order = min(board_orders(*INNER), key=lambda o: np.abs(seen[photos[0]] - true[photos[0]][o]).max())
    for name in photos:
        assert np.abs(seen[name] - true[name][order]).max() < 1.0, name
    result = place([model], None, markers=[found])
    record = result["markers"][0]
    error = _scale_error(model, marker_scene)
    print(f"chessboard: {len(photos)} of {found.photos_with_detections} photos with a board kept; model scale "
          f"{100 * error:+.3f} % from the truth, stated +-{100 * record['scale_relative_std']:.3f} %")
    assert result["scale_source"] == "chessboard" and record["set_scale"] and record["edges"] == INNER[0] + INNER[1]
    assert abs(error) < 0.01


def _projected(model_scene: Path, corners: np.ndarray, noise_px: float, rng) -> dict[str, np.ndarray]:
    """Photo -> the true ``corners`` projected (OpenCV's pixels) plus N(0, noise_px), in the photos
    that see them all inside the frame."""
    out = {}
    for name, cam in load_scene(model_scene).cameras().items():
        uv, z = cam.project(corners)
        uv = uv - 0.5
        if (z > 0).all() and (uv > 5).all() and (uv[:, 0] < cam.width - 5).all() and (uv[:, 1] < cam.height - 5).all():
            out[name] = uv + rng.normal(0, noise_px, uv.shape)
    return out


def test_board_orders_and_false_boards_on_projected_corners(marker_scene, marker_workspace):
    """Every photo's board corners as a detector may give them: from either end, mirrored; and one photo
    with a board that is not there. The target holds each photo's corners in the true order (up to
    one symmetry for all), leaves the false board out, and scales the model to the truth."""
    rng = np.random.default_rng(0)
    true = _projected(marker_scene, board_corners(), 0.1, rng)
    names = sorted(true)
    orders = board_orders(*INNER)
    given = {name: true[name][orders[k % len(orders)]] for k, name in enumerate(names)}
    false = names[3]
    given[false] = given[false] + rng.uniform(-40, 40, 2)  # a board assembled elsewhere in that photo
    model = _shrunk(marker_workspace)
    found = board_targets(model, given, Chessboard(*INNER, SQUARE), 16)
    (target,) = found.targets
    kept = [name for name, _, _ in target.corners[0]]
    assert false not in kept and len(kept) == len(names) - 1
    seen = {name: np.array([[x, y] for corner in target.corners for n, x, y in corner if n == name]) for name in kept}
    order = min(orders, key=lambda o: np.abs(seen[kept[0]] - true[kept[0]][o]).max())
    assert all(np.abs(seen[name] - true[name][order]).max() < 1e-9 for name in kept)
    place([model], None, markers=[found])
    assert abs(_scale_error(model, marker_scene)) < 0.005


def test_marker_scale_math_and_scale_bars_first(marker_scene, marker_workspace):
    """Projected marker corners (0.3 px noise) scale the model to the truth, with an uncertainty; with a
    scale bar given too, the bar sets the scale and the markers check it."""
    rng = np.random.default_rng(1)
    detections: dict[str, dict[int, np.ndarray]] = {}
    for marker, corners in marker_corners().items():
        for name, uv in _projected(marker_scene, corners, 0.3, rng).items():
            detections.setdefault(name, {})[marker] = uv
    found = marker_targets(detections, ArucoMarkers(size=MARKER_SIDE), 16)
    model = _shrunk(marker_workspace)
    result = place([model], None, markers=[found])
    record = result["markers"][0]
    assert result["scale_source"] == "ArUco markers" and record["edges"] == 8
    assert abs(_scale_error(model, marker_scene)) < 0.01 and 0 < record["scale_relative_std"] < 0.01
    assert record["scale"] == pytest.approx(1 / 0.37, rel=0.01)  # what the shrunk model needed

    model = _shrunk(marker_workspace)
    ends = marker_corners()[7][0], marker_corners()[3][2]  # a corner of each marker: 1 m or so apart
    marks = [_projected(marker_scene, end[None], 0.0, rng) for end in ends]
    bar = ScaleBar(length=float(np.linalg.norm(ends[0] - ends[1])),
                   a=[BarEnd(n, *uv[0]) for n, uv in marks[0].items()], b=[BarEnd(n, *uv[0]) for n, uv in marks[1].items()])
    result = place([model], None, scale_bars=[bar], markers=[found])
    record = result["markers"][0]
    assert result["scale_source"] == "scale bar" and not record["set_scale"]
    assert abs(record["scale"] - 1) < 0.01  # the markers agree with the bar


def test_no_marker_in_view_warns_and_leaves_the_scale(small_scene, copy_workspace):
    """Markers described but none in the photos: sfm finishes, the model keeps the mapper's scale, and
    the warning names the dictionary and the photos with detections."""
    recon.run(SPARSE_TEST, images=str(small_scene / "images"), workspace=str(copy_workspace),
              sfm={"aruco": {"dictionary": "DICT_5X5_100", "size": 0.2}})
    georef = json.loads((copy_workspace / "georeference.json").read_text())
    (record,) = georef["markers"]
    assert georef["scale_source"] == "none" and "model_scale" not in georef and not record["used"]
    message = ("sfm.aruco: DICT_5X5_100 markers of side 0.2 m: none was seen in 2 or more registered photos "
               "(detections in 0 of 16 photos); the model's scale does not come from them")
    assert record["reason"].startswith(message)
    assert message in (copy_workspace / ".recon" / "recon.log").read_text()


def test_target_options_are_checked_by_name(small_scene, tmp_path):
    images, ws = str(small_scene / "images"), str(tmp_path / "ws")
    with pytest.raises(ConfigError, match=r"^sfm\.chessboard\.rows: must be >= 2; got 1"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"chessboard": {"rows": 1, "square": 0.02}})
    with pytest.raises(ConfigError, match=r"^sfm\.aruco\.dictionary: must be one of DICT_4X4_50, .*; got 'DICT_4x4_50'"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"aruco": {"dictionary": "DICT_4x4_50", "size": 0.1}})
    with pytest.raises(ConfigError, match=r"^sfm\.aruco\.size: must be >= 0"):
        recon.run(SPARSE_TEST, images=images, workspace=ws, sfm={"aruco": {"size": -0.1}})
