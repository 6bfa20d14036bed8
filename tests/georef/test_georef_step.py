"""The sfm stage's georeferencing step on a real model (the shared sparse run of the small synthetic
scene), with GPS made from the true camera centres: the model (cameras and points) moves into the
ENU frame, georeference.json's content describes it, wrong GPS is named, too little GPS is refused."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.geometry.transforms import Similarity, umeyama
from recon.geometry.utm import enu_to_utm, utm_zone
from recon.sparse.georeference import georeference, place
from recon.synth import load_scene

ORIGIN = (-33.8568, 151.2153, 12.0)
METRES_PER_UNIT = 40.0
SIGMA = 1.0


def _truth() -> Similarity:
    yaw = np.radians(-70.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return Similarity(METRES_PER_UNIT, R, np.array([-5.0, 8.0, 3.0]))


def _gps(small_scene, bad=(), noise=SIGMA, seed=0) -> tuple[dict, dict]:
    """name -> gps record (as ingest writes it), and name -> true ENU centre at ORIGIN."""
    rng = np.random.default_rng(seed)
    truth = _truth()
    records, centres = {}, {}
    for name, cam in sorted(load_scene(small_scene).cameras().items()):
        centres[name] = truth.apply(-cam.R.T @ cam.t)
        measured = centres[name] + rng.normal(0, noise, 3) + (np.array([0.0, 100.0, 0.0]) if name in bad else 0)
        lat, lon, alt = wgs84_from_enu(measured, ORIGIN)[0]
        records[name] = {"lat": lat, "lon": lon, "alt": alt, "dop": None, "horizontal_error": noise}
    return records, centres


def _model(sparse_workspace):
    return pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))


def _centres_at_origin(model, result) -> dict:
    origin = tuple(result["origin"][k] for k in ("lat", "lon", "alt"))
    images = [img for img in model.images.values() if img.has_pose]
    placed = enu_from_wgs84(wgs84_from_enu(np.array([img.projection_center() for img in images]), origin), ORIGIN)
    return dict(zip((img.name for img in images), placed))


def test_model_moves_into_the_enu_frame(small_scene, sparse_workspace):
    model = _model(sparse_workspace)
    before = np.array([model.points3D[i].xyz for i in sorted(model.points3D)])
    gps, centres = _gps(small_scene)
    result = georeference([model], gps, seed=0)
    assert result["georeferenced"] and result["outliers"] == [] and result["other_models"] == []
    placed = _centres_at_origin(model, result)
    error = np.array([np.linalg.norm(placed[n] - centres[n]) for n in placed])
    assert len(placed) == 16 and np.median(error) < 1.0
    assert umeyama(np.array(list(placed.values())), np.array([centres[n] for n in placed])).s == pytest.approx(1, abs=0.01)
    # the points moved with the cameras, by the similarity georeference.json records
    sim = result["model_to_enu"]
    after = np.array([model.points3D[i].xyz for i in sorted(model.points3D)])
    expected = sim["scale"] * before @ np.asarray(sim["rotation"]).T + np.asarray(sim["translation"])
    assert after == pytest.approx(expected, abs=1e-6)
    # per photo: GPS and camera in the frame, and their distance
    for photo in result["photos"]:
        assert np.linalg.norm(np.subtract(photo["camera_enu"], photo["gps_enu"])) == pytest.approx(photo["residual_m"])
        assert photo["sigma_m"] == SIGMA and photo["inlier"]
    assert result["residuals_m"]["median"] < 3.368 * SIGMA and 0 < result["scale_relative_std"] < 0.01


def test_wrong_gps_is_named_and_left_out(small_scene, sparse_workspace):
    model = _model(sparse_workspace)
    bad = ("view_002.jpg", "view_009.jpg")
    gps, centres = _gps(small_scene, bad=bad)
    result = georeference([model], gps, seed=0)
    assert result["georeferenced"] and result["outliers"] == list(bad)
    placed = _centres_at_origin(model, result)
    assert np.median([np.linalg.norm(placed[n] - centres[n]) for n in placed]) < 1.0


def test_too_few_photos_with_gps_leave_the_model_alone(small_scene, sparse_workspace):
    model = _model(sparse_workspace)
    before = {i: img.projection_center() for i, img in model.images.items()}
    gps, _ = _gps(small_scene)
    few = dict(list(gps.items())[:8])  # half of the 16: not "more than half"
    result = georeference([model], few, seed=0)
    assert not result["georeferenced"] and result["reason"].startswith("8 of the 16 registered photos have")
    assert all(np.array_equal(model.images[i].projection_center(), c) for i, c in before.items())


def test_gps_that_contradicts_the_model_is_refused(small_scene, sparse_workspace):
    """GPS 20x worse than its stated accuracy: most photos disagree, so nothing is claimed."""
    model = _model(sparse_workspace)
    gps, _ = _gps(small_scene, noise=20.0)
    for record in gps.values():
        record["horizontal_error"] = 1.0
    result = georeference([model], gps, seed=0)
    assert not result["georeferenced"] and "sfm.gps_sigma" in result["reason"]
    assert georeference([model], gps, sigma=20.0, seed=0)["georeferenced"]  # told the real accuracy


def test_utm_frame_puts_the_cameras_at_their_utm_coordinates(small_scene, sparse_workspace):
    """sfm.crs utm: the camera centres land on their true positions as pyproj projects them to UTM
    zone 56S (Sydney), less the recorded offset; without GPS the frame stays and says why."""
    from pyproj import Transformer

    model = _model(sparse_workspace)
    gps, centres = _gps(small_scene)
    result = place([model], gps, seed=0, crs="utm")
    utm = result["utm"]
    assert utm["used"] and utm["epsg"] == 32756 and utm["zone"] == "56S" and result["crs"].startswith("EPSG:32756")
    assert all(v % 1000 == 0 for v in utm["offset"]) and utm["max_error_m"] < 0.01
    lla = wgs84_from_enu(np.array([centres[n] for n in sorted(centres)]), ORIGIN)
    easting, northing = Transformer.from_crs("EPSG:4326", "EPSG:32756", always_xy=True).transform(lla[:, 1], lla[:, 0])
    true = np.column_stack([easting, northing, lla[:, 2]]) - np.asarray(utm["offset"])
    found = {img.name: img.projection_center() for img in model.images.values() if img.has_pose}
    error = np.linalg.norm(np.array([found[n] for n in sorted(centres)]) - true, axis=1)
    assert np.median(error) < 1.0, np.median(error)
    unplaced = place([_model(sparse_workspace)], None, crs="utm")
    assert unplaced["utm"]["used"] is False and "not placed on the Earth" in unplaced["utm"]["why"]


@pytest.mark.parametrize(("lat", "lon", "epsg", "zone"), [(52.52, 13.40, 32633, "33N"), (-33.86, 151.21, 32756, "56S"),
                                                          (40.0, -179.9, 32601, "1N"), (0.0, 179.99, 32660, "60N")])
def test_utm_zone(lat, lon, epsg, zone):
    assert utm_zone(lat, lon) == (epsg, zone)


def test_enu_to_utm_follows_pyproj_over_two_kilometres():
    """The similarity stands in for pyproj's projection within centimetres over a 2 km survey at a
    zone's edge (largest convergence and scale factor); off-grid points check it independently."""
    from pyproj import Transformer

    origin = (47.3, 11.95, 600.0)  # 2.95 deg east of zone 32's central meridian
    extent = np.array([[-1000.0, -1000.0, -20.0], [1000.0, 1000.0, 80.0]])
    frame = enu_to_utm(origin, extent)
    assert frame.epsg == 32632 and frame.max_error_m < 0.2
    assert 0.9996 < frame.from_enu.s < 1.0006  # the point scale factor
    rng = np.random.default_rng(0)
    enu = rng.uniform(extent[0], extent[1], (50, 3))
    lla = wgs84_from_enu(enu, origin)
    easting, northing = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(lla[:, 1], lla[:, 0])
    true = np.column_stack([easting, northing, lla[:, 2]]) - np.asarray(frame.offset)
    assert np.abs(frame.from_enu.apply(enu) - true).max() < frame.max_error_m + 1e-6
