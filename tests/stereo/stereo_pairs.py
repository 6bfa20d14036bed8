"""The stereo tests' rendered pairs and scores (a module of its own, not conftest: test folders each
have a conftest, so `from conftest import` is ambiguous)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.eval.groundtruth import Camera

WIDTH, HEIGHT = 640, 480
BASELINE = 0.25  # scene depths 2.6..7.5: disparities of about 19..56 px at 640x480
#: the left camera: on the scene's orbit side, looking at its centre
LEFT_OFFSET = np.array([3.0, -1.5, 1.8])


@dataclass
class RenderedPair:
    left: Camera
    right: Camera
    left_image: np.ndarray
    right_image: np.ndarray
    left_depth: np.ndarray
    right_depth: np.ndarray


def make_pair(renderer, offset=(BASELINE, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0)) -> RenderedPair:
    """The left camera and a right camera whose centre is the left's moved by ``offset`` (in the left
    camera's axes: x right, y down), turned by the rotation vector ``rotation_deg`` (degrees, left
    camera axes), rendered."""
    from recon.synth.cameras import intrinsics, look_at
    from recon.synth.scene import TARGET

    K = intrinsics(WIDTH, HEIGHT)
    centre = TARGET + LEFT_OFFSET
    R, t = look_at(centre, TARGET)
    turn = cv2.Rodrigues(np.radians(np.asarray(rotation_deg, dtype=float)))[0]
    R2 = turn @ R
    centre2 = centre + R.T @ np.asarray(offset, dtype=float)
    left, right = Camera(K, R, t, WIDTH, HEIGHT), Camera(K, R2, -R2 @ centre2, WIDTH, HEIGHT)
    (li, ld, _), (ri, rd, _) = renderer.render(left), renderer.render(right)
    return RenderedPair(left, right, li, ri, ld, rd)


def pinhole(cam: Camera):
    from recon.imaging.intrinsics import Intrinsics

    return Intrinsics.pinhole(cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], cam.width, cam.height)


def textured_surface(image: np.ndarray, truth: np.ndarray, min_std: float = 0.02) -> np.ndarray:
    """Pixels on a surface (true depth > 0) whose grey level varies (std over 7 x 7 >= ``min_std``)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    mean = cv2.blur(grey, (7, 7))
    std = np.sqrt(np.maximum(cv2.blur(grey * grey, (7, 7)) - mean * mean, 0.0))
    return (truth > 0) & (std >= min_std)


def depth_scores(depth: np.ndarray, truth: np.ndarray, image: np.ndarray, tolerance: float = 0.01) -> dict:
    """Share of the depth pixels on textured surface within ``tolerance`` relative error, share of the
    textured surface with a depth, share of the no-surface (sky) pixels given a depth."""
    textured = textured_surface(image, truth)
    kept = (depth > 0) & textured
    error = np.abs(depth[kept] - truth[kept]) / truth[kept]
    sky = truth == 0
    return {"within": float((error < tolerance).mean()) if kept.any() else 0.0,
            "coverage": float(kept.sum() / max(textured.sum(), 1)),
            "sky_with_depth": float(((depth > 0) & sky).sum() / max(sky.sum(), 1))}
