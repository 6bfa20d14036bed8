"""Camera refinement after mapping: finer SIFT, matched only between photos the model shows overlapping.

How finely the keypoints locate sets how well the cameras come out: the zoo's 640x480 photos,
upsized to 800 px for SIFT and then to 1024 px (``features.min_image_size``), gave cameras whose median
relative rotation error fell on 15 of 17 scenes (glossy .137 -> .056 degrees). Going further at
mapping time does not pay: at 1280 px walkaround's photos matched the same window pictures on other
facades, and its model broke (pose AUC@5 95 -> 25). Here the finished model decides what is matched,
so those false pairs cannot come in:

1. every registered photo's SIFT again, upsized to ``sfm.refine_image_size`` px (its longest side), with
   the features stage's settings and its ladder for photos giving few features;
2. matched only between photos sharing :data:`MIN_SHARED_POINTS` of the model's points (each with the
   :data:`MAX_PARTNERS` sharing the most with it), a match kept where the model's own epipolar geometry
   holds it (Sampson distance within :data:`MAX_EPIPOLAR_PX`);
3. the points triangulated again at the model's poses (COLMAP's point triangulator,
   ``pycolmap.triangulate_points``), and the model's last bundle adjustment run again
   (:func:`recon.sparse.mapping.final_bundle_adjustment`), unless the finer features give fewer
   observations than the model holds (turntable_black's dark marble: 6,986 against 7,997).

Two choices in step 3, measured on walkaround and street_forward (session 60, docs/DECISIONS.md): the
bundle adjustment keeps the loose points (dropped, as the mapper's last one drops them, walkaround's
relative rotation error went .236 -> .339 degrees instead of -> .170: its four facades are joined by few
points at the corners), and it keeps distortion only where that explains the observations better
(refined freely, street_forward's k1 came out 2e-4 where the truth is 0, the undistort stage then
resampled its photos, and its fused F@0.2 % fell .007).

Off by default (``sfm.refine_image_size`` 0): the cameras come out closer to the truth (zoo: glossy
.056 -> .036 degrees, walkaround .236 -> .175, far_field .036 -> .027; temple_ring's pose AUC@1/3/5
73.9 / 91.2 / 94.7 -> 77.9 / 92.6 / 95.5), but the dense cloud follows on glossy alone (fused F@0.2 %
.9503 -> .9566; far_field .9641 -> .9646, transient_car .9515 -> .9500, walkaround, the zoo's worst,
.8738 -> .8693), for about a minute more per 24 photos on two cores.

Only photos smaller than that size are refined: the gain is the finer keypoints (street_forward's
features from the features stage, matched and triangulated so, gave worse cameras: .0096 -> .0131
degrees), and what larger photos gain above their features' size is not measured. Only models of
perspective cameras, one camera per frame, are refined (fisheye, 360 and rig models are left as the
mapper made them), and only models mapped from scratch (a continued model keeps its earlier photos' poses).
The refined features do not leave masked pixels out (``features.masks``): a background that does not move
with a turntable's object matches at the same pixels in every photo, which mostly lie off the model's
epipolar geometry (not measured).
"""

from __future__ import annotations

import logging
import tempfile
import time
from collections import Counter
from itertools import combinations
from pathlib import Path

import numpy as np

from recon.sparse.database import sift_descriptors
from recon.sparse.pose_check import epipolar_px
from recon.sparse.sift_match import sift_matches

log = logging.getLogger(__name__)

#: two photos are matched again where they share at least this many of the model's points
MIN_SHARED_POINTS = 15
#: each photo is matched again with at most this many of the photos sharing the most points with it
MAX_PARTNERS = 20
#: a new match is kept where its Sampson distance to the model's epipolar geometry is at most this (px)
MAX_EPIPOLAR_PX = 1.0


def refinable(rec, size: int) -> str | None:
    """Why ``rec`` is not refined at ``size`` px (photos that large already, fisheye or 360 cameras, rigs
    of several cameras), or None."""
    largest = max(max(camera.width, camera.height) for camera in rec.cameras.values())
    if largest >= size:
        return f"its photos are {largest} px (sfm.refine_image_size {size}: only smaller photos are refined)"
    if not all(camera.is_perspective_pinhole() for camera in rec.cameras.values()):
        return "it holds fisheye or 360 cameras"
    if any(rig.num_sensors() > 1 for rig in rec.rigs.values()):
        return "it holds rigs of several cameras"
    return None


def overlapping_pairs(rec, min_shared: int = MIN_SHARED_POINTS, partners: int = MAX_PARTNERS) -> list[tuple[int, int]]:
    """Pairs of registered image ids (smaller first) sharing at least ``min_shared`` of ``rec``'s points, each
    among the ``partners`` pairs sharing the most of one of its two photos (a long video's frames would
    otherwise pair with every frame in view)."""
    shared: Counter = Counter()
    for point in rec.points3D.values():
        shared.update(combinations(sorted({el.image_id for el in point.track.elements}), 2))
    ranked: dict[int, list[tuple[int, tuple[int, int]]]] = {}
    for pair, count in shared.items():
        if count >= min_shared:
            for image_id in pair:
                ranked.setdefault(image_id, []).append((count, pair))
    return sorted({pair for pairs in ranked.values() for _, pair in sorted(pairs, reverse=True)[:partners]})


def refine(rec, features: dict[int, tuple[np.ndarray, np.ndarray]], photos: Path, cfg,
           initial: dict[int, np.ndarray], exif_focal: frozenset[int]):
    """``rec`` with its points triangulated again from ``features`` (image id -> keypoints in the photo's
    pixels, descriptors) at its poses, then adjusted (module doc); ``cfg`` is the sfm stage's config,
    ``initial`` and ``exif_focal`` as :func:`recon.sparse.mapping.final_bundle_adjustment` takes them."""
    import pycolmap

    from recon.sparse.mapping import colmap_threads, final_bundle_adjustment

    start = time.perf_counter()
    pairs = overlapping_pairs(rec)
    found = kept = 0
    with tempfile.TemporaryDirectory(prefix="recon-refine-") as scratch:
        path = Path(scratch) / "refine.db"
        db = pycolmap.Database.open(str(path))
        try:
            for camera in rec.cameras.values():
                db.write_camera(camera, use_camera_id=True)
            for image_id, (keypoints, descriptors) in features.items():
                image = rec.image(image_id)
                db.write_image(pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image_id),
                               use_image_id=True)
                db.write_keypoints(image_id, keypoints)
                db.write_descriptors(image_id, sift_descriptors(descriptors))
            for a, b in pairs:
                matches = sift_matches(features[a][1], features[b][1])
                if not len(matches):
                    continue
                distances = epipolar_px(rec, a, b, features[a][0][matches[:, 0], :2],
                                        features[b][0][matches[:, 1], :2])
                if distances is None:  # the same centre: no epipolar geometry to check the matches against
                    continue
                good = distances <= MAX_EPIPOLAR_PX
                found += len(matches)
                kept += int(good.sum())
                db.write_matches(a, b, matches.astype(np.uint32))
                geometry = pycolmap.TwoViewGeometry()
                geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
                geometry.inlier_matches = matches[good].astype(np.uint32)
                db.write_two_view_geometry(a, b, geometry)
        finally:
            db.close()
        out = Path(scratch) / "model"
        out.mkdir()
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = colmap_threads(cfg)
        triangulated = pycolmap.triangulate_points(pycolmap.Reconstruction(rec), str(path), str(photos), str(out),
                                                   clear_points=True, options=options, refine_intrinsics=False)
    log.info("sfm: refinement: %d overlapping pairs, %d of %d finer matches on the model's epipolar geometry, "
             "%d points (were %d) from %d observations (were %d)", len(pairs), kept, found,
             triangulated.num_points3D(), rec.num_points3D(), triangulated.compute_num_observations(),
             rec.compute_num_observations())
    if triangulated.compute_num_observations() < rec.compute_num_observations():
        log.info("sfm: refinement left out: the finer features gave fewer observations than the model's")
        return rec
    refined = final_bundle_adjustment(triangulated, cfg, initial, exif_focal, drop_loose=False)
    log.info("sfm: refinement done in %.1f s: mean reprojection error %.3f px (was %.3f)",
             time.perf_counter() - start, refined.compute_mean_reprojection_error(),
             rec.compute_mean_reprojection_error())
    return refined

