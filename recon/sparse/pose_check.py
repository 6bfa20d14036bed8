"""Photos whose registered pose contradicts the verified geometry of their strongest pairs.

The incremental mapper registers a photo from its 2D-3D matches to the model. Where most of those are
false (the far side of an object that looks alike), the photo can be placed wrongly with a low
reprojection error: on masked_object with 16 photos (zoo, 640x480), view_005 was registered through 57
points shared with photos across the object and put 9 times too far from it, although it shares 214
and 240 verified inliers with its two neighbours. Its texture and depth maps then spoil the dense
result (held-out texture 20 dB against 32), and nothing in the model's figures shows it.

The pairs' verified inliers are evidence the mapper does not use once a photo is registered. For each
registered photo, its :data:`TOP_PAIRS` strongest pairs with other registered photos (at least
:data:`MIN_PAIR_INLIERS` inliers) are checked against the model: the share of each pair's inlier
matches within :data:`MAX_EPIPOLAR_PX` (Sampson distance) of the epipolar geometry that the two
registered poses imply. A photo is contradicted when most of its checked pairs agree on under
:data:`MIN_AGREEING` of their inliers; one disagreeing pair can be a false pair (a repeated texture),
or its partner can be the misplaced photo. Measured on 49 models: the 15 zoo scenes with 24 and with
16 photos, 16 zoo models from 12 photos and the real photo sets (temple_ring, fountain_p11,
dino_sparse_ring). No right pose was flagged, and the median pair agrees on all its inliers. Two models
had photos flagged, and every flagged photo was wrong: view_005 above, and four photos of turntable_black
(12 photos at 480x360, the global mapper's model) that were 75-170 degrees off.

A photo taken out is then given one more chance: the incremental mapper, continuing the model without it,
registers it again through its verified pairs (:func:`recon.sparse.mapping._registered_again`); a wrong
pose is not always the photo's own fault (one of the mapper's initial pair can keep one).

Only perspective cameras are checked (and paired): the distance is measured on the image plane, which a
fisheye's or a 360 camera's rays behind it do not reach.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from recon.sparse.database import read_inlier_matches, read_keypoints, read_only

log = logging.getLogger(__name__)

TOP_PAIRS = 3
MIN_PAIR_INLIERS = 50
#: COLMAP's two-view verification keeps matches within 4 px of the epipolar geometry
MAX_EPIPOLAR_PX = 4.0
MIN_AGREEING = 0.5


def contradicted(rec, database: Path) -> dict[int, str]:
    """Image id -> why, for the registered photos of ``rec`` whose pose their strongest verified
    pairs contradict (module doc)."""
    import pycolmap

    registered = _perspective_registered(rec)
    out = {}
    with read_only(database) as db:
        pairs: dict[int, list[tuple[int, int]]] = {}
        for pair_id, inliers in db.execute("SELECT pair_id, rows FROM two_view_geometries"):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            if a in registered and b in registered and inliers >= MIN_PAIR_INLIERS:
                pairs.setdefault(a, []).append((inliers, b))
                pairs.setdefault(b, []).append((inliers, a))
        keypoints: dict[int, np.ndarray] = {}
        shares: dict[tuple[int, int], float | None] = {}  # each pair's, measured once

        def pixels(image_id: int) -> np.ndarray:  # each photo's keypoints, read once
            if image_id not in keypoints:
                keypoints[image_id] = read_keypoints(db, image_id)[:, :2].astype(np.float64)
            return keypoints[image_id]

        for image_id in sorted(registered):
            checked = []
            for inliers, other in sorted(pairs.get(image_id, []), reverse=True)[:TOP_PAIRS]:
                a, b = min(image_id, other), max(image_id, other)
                if (a, b) not in shares:
                    matches = read_inlier_matches(db, pycolmap.image_pair_to_pair_id(a, b))
                    shares[a, b] = agreement(rec, a, b, pixels(a)[matches[:, 0]], pixels(b)[matches[:, 1]])
                if shares[a, b] is not None:
                    checked.append((rec.image(other).name, inliers, shares[a, b]))
            if checked and sum(share < MIN_AGREEING for _, _, share in checked) > len(checked) / 2:
                out[image_id] = ("registered where its strongest verified pairs contradict its pose (" +
                                 ", ".join(f"{name}: {share:.0%} of {n} inliers agree" for name, n, share in checked)
                                 + "); taken out of the model")
    return out


def pair_pixels(rec, database: Path, min_inliers: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Pair id -> the pixels of its verified inlier matches (M x 2 each, row for row: the first photo's,
    the second's) for every verified pair of ``rec``'s registered perspective photos with at least
    ``min_inliers`` inliers; read once, then judged against any model by :func:`pair_agreement`."""
    import pycolmap

    registered = _perspective_registered(rec)
    out = {}
    with read_only(database) as db:
        keypoints = {image_id: read_keypoints(db, image_id)[:, :2].astype(np.float64) for image_id in registered}
        for pair_id, in db.execute("SELECT pair_id FROM two_view_geometries WHERE rows >= ?", (min_inliers,)).fetchall():
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            if a in registered and b in registered:
                matches = read_inlier_matches(db, pair_id)
                out[pair_id] = (keypoints[a][matches[:, 0]], keypoints[b][matches[:, 1]])
    return out


def pair_agreement(rec, pixels: dict[int, tuple[np.ndarray, np.ndarray]]) -> dict[int, float]:
    """Pair id -> the share of its inlier matches (``pixels``: :func:`pair_pixels`) that agree with ``rec``'s
    poses (:func:`agreement`), for the pairs both of whose photos ``rec`` registers."""
    import pycolmap

    registered = set(rec.reg_image_ids())
    out = {}
    for pair_id, (pixels_a, pixels_b) in pixels.items():
        a, b = pycolmap.pair_id_to_image_pair(pair_id)
        if a in registered and b in registered:
            share = agreement(rec, a, b, pixels_a, pixels_b)
            if share is not None:
                out[pair_id] = share
    return out


def _perspective_registered(rec) -> set[int]:
    """Ids of ``rec``'s registered photos with a perspective camera (the only ones checked: module doc)."""
    return {image_id for image_id in rec.reg_image_ids()
            if rec.camera(rec.image(image_id).camera_id).is_perspective_pinhole()}


def agreement(rec, a: int, b: int, pixels_a: np.ndarray, pixels_b: np.ndarray) -> float | None:
    """The share of the inlier matches of images ``a`` and ``b`` (their pixels: M x 2 each, row for row)
    within :data:`MAX_EPIPOLAR_PX` of the epipolar geometry of their poses in ``rec``; None where the two
    centres coincide (no epipolar geometry)."""
    distances = epipolar_px(rec, a, b, pixels_a, pixels_b)
    return None if distances is None else float(np.mean(distances < MAX_EPIPOLAR_PX))


def epipolar_px(rec, a: int, b: int, pixels_a: np.ndarray, pixels_b: np.ndarray) -> np.ndarray | None:
    """Sampson distance (px at the two cameras' mean focal length) of each correspondence (``pixels_a``
    (M, 2) in image ``a``, ``pixels_b`` in ``b``, row for row) to the epipolar geometry of their poses in
    ``rec``; None where the two centres coincide (no epipolar geometry)."""
    image_a, image_b = rec.image(a), rec.image(b)
    cam_a, cam_b = rec.camera(image_a.camera_id), rec.camera(image_b.camera_id)
    rays = [np.c_[cam.cam_from_img(np.asarray(pixels, np.float64)), np.ones(len(pixels))]
            for cam, pixels in ((cam_a, pixels_a), (cam_b, pixels_b))]
    pose_a, pose_b = image_a.cam_from_world(), image_b.cam_from_world()
    rotation = pose_b.rotation.matrix() @ pose_a.rotation.matrix().T
    baseline = pose_b.translation - rotation @ pose_a.translation
    if np.linalg.norm(baseline) < 1e-9:
        return None
    tx, ty, tz = baseline / np.linalg.norm(baseline)
    essential = np.array([[0.0, -tz, ty], [tz, 0.0, -tx], [-ty, tx, 0.0]]) @ rotation
    line_b, line_a = rays[0] @ essential.T, rays[1] @ essential
    sampson = np.sum(rays[1] * line_b, axis=1) ** 2 / (line_b[:, 0] ** 2 + line_b[:, 1] ** 2 +
                                                        line_a[:, 0] ** 2 + line_a[:, 1] ** 2)
    focal = 0.5 * (cam_a.mean_focal_length() + cam_b.mean_focal_length())
    return np.sqrt(sampson) * focal


def take_out_contradicted(rec, database: Path) -> dict[str, str]:
    """Deregister the photos of ``rec`` that :func:`contradicted` finds; their names -> why."""
    found = contradicted(rec, database)
    for image_id, why in found.items():
        log.info("sfm: %s %s", rec.image(image_id).name, why)
        rec.deregister_frame(rec.image(image_id).frame_id)
    return {rec.image(image_id).name: why for image_id, why in found.items()}
