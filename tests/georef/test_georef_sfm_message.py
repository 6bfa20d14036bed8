"""sfm's "no model" message says what the database shows actually failed (issue 13: it used to say
"29 photos have matches but 54 pair(s) have the 100+ inliers needed" and never mention EXIF)."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from recon.sparse.mapping import registration_report

Config = pycolmap.TwoViewGeometryConfiguration


def _database(path, pairs: dict[tuple[int, int], tuple[int, Config]], prior_focal: bool, focal: float = 384.0):
    """A COLMAP database of 5 photos (320x240, one camera) with verified pairs (inliers, config)."""
    db = pycolmap.Database.open(str(path))
    camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=320, height=240, params=[focal, 160, 120, 0])
    camera.has_prior_focal_length = prior_focal
    camera_id = db.write_camera(camera)
    for k in range(5):
        db.write_image(pycolmap.Image(name=f"p{k}.jpg", camera_id=camera_id))
    for (a, b), (inliers, config) in pairs.items():
        geometry = pycolmap.TwoViewGeometry()
        geometry.config = config
        geometry.inlier_matches = np.tile(np.arange(inliers, dtype=np.uint32)[:, None], (1, 2))
        db.write_two_view_geometry(a, b, geometry)
    db.close()
    return path


def _reason(tmp_path, pairs, prior_focal, focal=384.0) -> str:
    report = registration_report(_database(tmp_path / "database.db", pairs, prior_focal, focal), [], 15, 16.0)
    assert report["models"] == [] and len(report["unregistered"]) == 5
    return report["reason"]


def test_strong_pairs_contradicting_the_focal_priors_name_the_priors_first(tmp_path):
    """Focal priors from EXIF, and the pairs fit a fundamental matrix but not the essential matrix
    those priors imply: the message names the priors (with their field of view) first."""
    pairs = {(1, 2): (240, Config.UNCALIBRATED), (2, 3): (180, Config.UNCALIBRATED), (3, 4): (90, Config.CALIBRATED),
             (4, 5): (150, Config.CALIBRATED)}
    reason = _reason(tmp_path, pairs, prior_focal=True, focal=4000.0)  # 5.7 degrees: an absurd prior
    assert reason.startswith("No initial pair: 3 pair(s) have the 100+ verified inliers")
    causes = reason.split("Likely causes: ")[1]
    assert causes.startswith("wrong focal length priors: 2 of those pairs contradict")
    assert "6 degree field of view" in causes and "EXIF" in causes
    assert "sfm.init_min_tri_angle (now 16 degrees)" in causes
    assert "have matches but" not in reason  # the old, self-contradictory wording


def test_no_strong_pair_says_so_with_the_best_count(tmp_path):
    pairs = {(1, 2): (60, Config.CALIBRATED), (2, 3): (42, Config.CALIBRATED)}
    reason = _reason(tmp_path, pairs, prior_focal=True)
    assert reason.startswith("No initial pair: 3 photos have matches, but no pair has the 100+ verified inliers")
    assert "(the best has 60)" in reason and "Likely causes" not in reason


def test_homography_pairs_and_guessed_focal(tmp_path):
    pairs = {(1, 2): (300, Config.PANORAMIC), (2, 3): (250, Config.PLANAR_OR_PANORAMIC),
             (3, 4): (120, Config.UNCALIBRATED)}
    reason = _reason(tmp_path, pairs, prior_focal=False)
    causes = reason.split("Likely causes: ")[1].split("; ")
    assert causes[0].startswith("2 of those pairs fit a homography")
    assert causes[1].startswith("no EXIF focal length: the cameras start from a guess (55 degree")
    assert causes[2].startswith("too little baseline")


def test_too_few_matches(tmp_path):
    reason = _reason(tmp_path, {(1, 2): (10, Config.CALIBRATED)}, prior_focal=True)
    assert reason.startswith("Too few matches: no pair of the 5 photos shares 15+ verified matches")


@pytest.mark.parametrize("prior", [True, False])
def test_registered_photos_give_no_reason(tmp_path, prior):
    db = _database(tmp_path / "database.db", {(1, 2): (300, Config.CALIBRATED)}, prior)
    assert registration_report(db, [pycolmap.Reconstruction()], 15)["reason"] == ""
