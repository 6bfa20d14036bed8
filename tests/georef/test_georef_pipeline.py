"""Issue 16, "Done when" 1: a synthetic scene whose photos carry GPS (the true camera centres in an ENU
frame at a known origin, in metres, plus sigma = 3 m noise per axis), through the sparse pipeline:
the georeferenced camera centres lie within 1.5 m (median) of the truth and the scale is within 1 %;
three photos given GPS 100 m off are named as outliers and the rest still meet these figures."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest

import recon
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.geometry.transforms import Similarity, umeyama
from recon.synth.geotags import GeoTag, write_gps

REPO = Path(__file__).resolve().parents[2]
SPARSE_TEST = REPO / "tests" / "sparse_test.yaml"
ORIGIN = (47.3769, 8.5417, 430.0)  # where the test puts the scene (lat, lon, alt)
METRES_PER_UNIT = 40.0  # the 3.5-unit orbit becomes 140 m: a drone circling a building
SIGMA = 3.0
OUTLIERS = ("view_004.jpg", "view_015.jpg", "view_027.jpg")
VIEWS = 36


def _world_to_enu() -> Similarity:
    yaw = np.radians(25.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return Similarity(METRES_PER_UNIT, R, np.array([30.0, -20.0, 15.0]))


@pytest.fixture(scope="module")
def gps_scene(tmp_path_factory):
    """The rendered scene and the true ENU camera centres (metres, in the frame at ORIGIN)."""
    from recon.synth import render_scene

    scene = render_scene(tmp_path_factory.mktemp("gps") / "scene", views=VIEWS, width=320, height=240, seed=0)
    truth = _world_to_enu()
    centres = {name: truth.apply(-cam.R.T @ cam.t) for name, cam in scene.cameras().items()}
    return scene, centres


def _tagged_photos(scene, centres: dict, folder: Path, outliers: tuple[str, ...]) -> Path:
    """Copies of the scene's photos with EXIF GPS: truth + N(0, SIGMA) per axis; outliers 100 m off."""
    rng = np.random.default_rng(42)
    shutil.copytree(scene.images_dir, folder)
    for name, enu in sorted(centres.items()):
        noisy = enu + rng.normal(0, SIGMA, 3)
        if name in outliers:
            direction = rng.normal(size=3)
            noisy = enu + 100.0 * direction / np.linalg.norm(direction)
        lat, lon, alt = wgs84_from_enu(noisy, ORIGIN)[0]
        write_gps(folder / name, GeoTag(lat, lon, alt, horizontal_error=SIGMA))
    return folder


def _georeferenced_run(scene, centres, tmp_path, outliers):
    images = _tagged_photos(scene, centres, tmp_path / "photos", outliers)
    ws = tmp_path / "ws"
    recon.run(SPARSE_TEST, images=str(images), workspace=str(ws))
    georef = json.loads((ws / "georeference.json").read_text())
    assert georef["georeferenced"], georef.get("reason")
    model = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    # the model's frame is the ENU frame at georef's origin; the truth is in the frame at ORIGIN
    origin = tuple(georef["origin"][k] for k in ("lat", "lon", "alt"))
    found = {img.name: img.projection_center() for img in model.images.values() if img.has_pose}
    names = sorted(found)
    placed = enu_from_wgs84(wgs84_from_enu(np.array([found[n] for n in names]), origin), ORIGIN)
    true = np.array([centres[n] for n in names])
    return ws, georef, names, placed, true


def _assert_figures(names, placed, true, georef):
    assert len(names) == VIEWS
    error = np.linalg.norm(placed - true, axis=1)
    scale = umeyama(placed, true).s  # 1 when the model is in true metres
    print(f"camera centres vs truth: median {np.median(error):.2f} m, max {error.max():.2f} m; scale error "
          f"{100 * (scale - 1):+.2f} %, stated {100 * georef['scale_relative_std']:.2f} %; GPS residuals median "
          f"{georef['residuals_m']['median']:.2f} m, p90 {georef['residuals_m']['p90']:.2f} m")
    assert np.median(error) < 1.5
    assert abs(scale - 1) < 0.01
    assert georef["scale_relative_std"] < 0.01


@pytest.mark.slow
def test_gps_noise_only(gps_scene, tmp_path):
    scene, centres = gps_scene
    ws, georef, names, placed, true = _georeferenced_run(scene, centres, tmp_path, outliers=())
    _assert_figures(names, placed, true, georef)
    assert georef["outliers"] == []
    by_name = {p["name"]: p for p in georef["photos"]}
    assert by_name.keys() == set(names) and all(p["sigma_m"] == SIGMA for p in by_name.values())
    # exports follow the frame: transforms.json's camera positions are the georeferenced centres
    frames = json.loads((ws / "transforms.json").read_text())["frames"]
    for frame in frames:
        name = Path(frame["file_path"]).name
        assert np.asarray(frame["transform_matrix"])[:3, 3] == pytest.approx(by_name[name]["camera_enu"], abs=1e-3)


@pytest.mark.slow
def test_gross_gps_outliers_are_named(gps_scene, tmp_path):
    scene, centres = gps_scene
    _, georef, names, placed, true = _georeferenced_run(scene, centres, tmp_path, outliers=OUTLIERS)
    assert sorted(georef["outliers"]) == list(OUTLIERS)
    residuals = {p["name"]: p["residual_m"] for p in georef["photos"]}
    assert all(residuals[n] > 80 for n in OUTLIERS)
    _assert_figures(names, placed, true, georef)
