"""The foreground's depth carried onto the background beside a silhouette is dropped
(recon.mvs.fattening), and correct depths stay."""

from __future__ import annotations

import cv2
import numpy as np
from plane_views import FOCAL, H, W, camera, texture

from recon.mvs.fattening import drop_fattened
from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import Camera

NEAR, FAR = 2.0, 4.0  # depths of the foreground square and of the background wall
HALF = 0.35  # the square's half side
#: px of background beside the silhouette that carry the foreground's depth (within the window's radius)
FAT = 3
#: camera centres: the reference and its sources, beside and above it
CENTRES = ((0.0, 0.0), (0.3, 0.0), (-0.3, 0.0), (0.0, 0.25), (0.2, -0.2))


def render(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Photo and true depth map of the square in front of the wall, seen by ``cam``."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dx, dy = (u - W / 2) / FOCAL, (v - H / 2) / FOCAL
    cx, cy = -cam.t[0], -cam.t[1]
    on_square = (np.abs(cx + NEAR * dx) < HALF) & (np.abs(cy + NEAR * dy) < HALF)
    depth = np.where(on_square, NEAR, FAR).astype(np.float32)
    image = np.where(on_square, texture(cx + NEAR * dx, cy + NEAR * dy, 1), texture(cx + FAR * dx, cy + FAR * dy, 2))
    return image.astype(np.float32), depth


def fattened(depth: np.ndarray) -> np.ndarray:
    """The depth map with the foreground's depth carried :data:`FAT` px onto the background around it."""
    grown = cv2.dilate((depth == NEAR).astype(np.uint8), np.ones((2 * FAT + 1, 2 * FAT + 1), np.uint8)) > 0
    return np.where(grown, NEAR, depth).astype(np.float32)


def scene(fatten: bool):
    views = [render(camera(*c)) for c in CENTRES]
    depths = [fattened(d) if fatten else d for _, d in views]
    return views, depths


def run(fatten: bool):
    views, depths = scene(fatten)
    depth = depths[0].copy()
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = -1
    dropped = drop_fattened(views[0][0], camera(*CENTRES[0]), depth, normal, [im for im, _ in views[1:]],
                            [camera(*c) for c in CENTRES[1:]], depths[1:], MVSOptions())
    return views[0][1], depths[0], depth, normal, dropped


def test_most_of_the_skirt_goes_and_the_correct_depths_stay():
    truth, before, after, normal, dropped = run(fatten=True)
    skirt = before != truth
    correct = (before == truth) & (before > 0)
    assert skirt.sum() > 500
    assert np.count_nonzero(skirt & (after == 0)) >= 0.6 * skirt.sum()
    assert np.count_nonzero(correct & (after == 0)) <= 0.02 * correct.sum()
    assert dropped == np.count_nonzero(after == 0)
    assert not normal[after == 0].any()


def test_correct_depths_at_a_silhouette_stay():
    truth, before, after, _, dropped = run(fatten=False)
    assert np.array_equal(before, truth)
    assert dropped <= 0.01 * truth.size
