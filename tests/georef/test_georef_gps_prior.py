"""GPS as a prior in a last bundle adjustment (issue 16, "GPS used as a prior in the final bundle
adjustment"): used by ``auto`` for accurate (RTK-grade) GPS only, it pulls the model onto the GPS
positions; RTK drones' accuracy is read from their XMP."""

from __future__ import annotations

import numpy as np
import pycolmap
from control_scene import ORIGIN, true_enu

from recon.geometry.gps import enu_from_wgs84, read_xmp_drone, wgs84_from_enu
from recon.sparse.georeference import georeference, gps_sigma
from recon.sparse.gps_prior import AUTO_MAX_SIGMA, decide
from recon.sparse.mapping import ba_options
from recon.stages.sfm import SfmConfig
from recon.synth import load_scene

RTK_SIGMA = 0.02  # metres


def test_auto_uses_accurate_gps_only():
    assert decide("auto", np.full(10, RTK_SIGMA))[0]
    assert decide("auto", np.full(10, AUTO_MAX_SIGMA))[0]
    used, why = decide("auto", np.full(10, 3.0))
    assert not used and "3 m" in why and "sfm.gps_prior: on" in why
    assert decide("on", np.full(10, 3.0)) == (True, "sfm.gps_prior is on")
    assert decide("off", np.full(10, RTK_SIGMA)) == (False, "sfm.gps_prior is off")


def test_auto_uses_coarse_gps_where_the_photos_fall_into_loosely_tied_groups():
    used, why = decide("auto", np.full(10, 3.0), groups=4)
    assert used and why.startswith("the model's photos fall into 4 groups tied to each other by few 3D points")
    assert not decide("auto", np.full(10, 3.0), groups=1)[0]
    assert decide("off", np.full(10, 3.0), groups=4) == (False, "sfm.gps_prior is off")


def test_rtk_accuracy_is_read_from_dji_xmp():
    xmp = (b'<rdf:Description drone-dji:RtkFlag="50" drone-dji:RtkStdLon="0.011" drone-dji:RtkStdLat="0.014" '
           b'drone-dji:RtkStdHgt="0.025"/>')
    tag = read_xmp_drone(xmp)
    assert tag == {"rtk_std_lon": 0.011, "rtk_std_lat": 0.014}
    assert gps_sigma(tag, 0.0) == 0.014  # the larger horizontal one
    assert gps_sigma({**tag, "horizontal_error": 0.05}, 0.0) == 0.05  # EXIF's own figure first
    assert gps_sigma({"dop": 4.0}, 0.0) == 4.0 and gps_sigma(tag, 1.5) == 1.5


def _gps(small_scene, sigma: float, bend: float = 0.0) -> tuple[dict, dict]:
    """GPS records stating accuracy ``sigma`` for the small scene's photos at their true places (ENU
    metres at ORIGIN), those east of the middle raised by up to ``bend`` metres (a smooth deformation
    no similarity takes out); and the true ENU centres."""
    truth = true_enu()
    true = {n: truth.apply(c.center) for n, c in load_scene(small_scene).cameras().items()}
    east = np.array([enu[0] for enu in true.values()])
    middle, half = np.median(east), np.ptp(east) / 2
    gps = {}
    for name, enu in true.items():
        lifted = enu + [0.0, 0.0, bend * max(0.0, (enu[0] - middle) / half) ** 2]
        lat, lon, alt = wgs84_from_enu(lifted, ORIGIN)[0]
        gps[name] = {"lat": lat, "lon": lon, "alt": alt, "horizontal_error": sigma}
    return gps, true


def _georeferenced(sparse_workspace, gps: dict, prior: str | None) -> tuple[dict, dict]:
    """The shared sparse model georeferenced from ``gps`` with ``prior``: georeference.json and the
    camera centres in the ENU frame at ORIGIN."""
    model = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    result = georeference([model], gps, prior=prior, ba_options=ba_options(SfmConfig(), principal_point=False))
    origin = tuple(result["origin"][k] for k in ("lat", "lon", "alt"))
    names = sorted(img.name for img in model.images.values() if img.has_pose)
    found = enu_from_wgs84(wgs84_from_enu(np.array([model.find_image_with_name(n).projection_center()
                                                    for n in names]), origin), ORIGIN)
    return result, dict(zip(names, found))


def test_each_camera_is_pulled_toward_its_own_gps_position(small_scene, sparse_workspace):
    """GPS that bends the scene (0.3 m over half of it, stated to 2 cm): the robust similarity leaves
    the bent photos out as outliers; the prior adjustment pulls each other camera toward its own GPS
    position (photo by photo, at its stated accuracy) while the photos keep their reprojection error."""
    gps, _ = _gps(small_scene, RTK_SIGMA, bend=0.3)
    target = enu_from_wgs84(np.array([[g["lat"], g["lon"], g["alt"]] for g in gps.values()]), ORIGIN)
    target = dict(zip(gps, target))
    placed, before = _georeferenced(sparse_workspace, gps, "off")
    adjusted, after = _georeferenced(sparse_workspace, gps, "auto")
    assert 0 < len(placed["outliers"]) < 8
    inliers = sorted(set(before) - set(placed["outliers"]))
    miss_before = np.array([np.linalg.norm(before[n] - target[n]) for n in inliers])
    miss_after = np.array([np.linalg.norm(after[n] - target[n]) for n in inliers])
    rms_before, rms_after = np.sqrt(np.mean(miss_before**2)), np.sqrt(np.mean(miss_after**2))
    print(f"{len(inliers)} inlier camera centres to their GPS: similarity only RMS {rms_before:.4f} m, max "
          f"{miss_before.max():.4f} m; after the GPS prior BA RMS {rms_after:.4f} m, max {miss_after.max():.4f} m; "
          f"{adjusted['gps_prior']}")
    assert placed["gps_prior"] == {"used": False, "why": "sfm.gps_prior is off"}
    prior = adjusted["gps_prior"]
    assert prior["used"] and prior["photos"] == len(inliers)
    assert prior["reprojection_error_px"]["after"] < 1.1 * prior["reprojection_error_px"]["before"]
    assert rms_after < 0.75 * rms_before
    assert adjusted["residuals_m"]["median"] < placed["residuals_m"]["median"]  # the record is after the adjustment


def test_coarse_gps_and_continued_models_get_no_prior(small_scene, sparse_workspace):
    gps, _ = _gps(small_scene, 3.0)
    coarse, _ = _georeferenced(sparse_workspace, gps, "auto")
    assert not coarse["gps_prior"]["used"] and "above 0.5 m" in coarse["gps_prior"]["why"]
    continued, _ = _georeferenced(sparse_workspace, gps, None)
    assert continued["gps_prior"] == {"used": False, "why": "a continued model keeps its photos' poses"}
