"""Camera paths for the synthetic scene, as pure functions (no rendering).

``orbit``: views evenly spaced in azimuth on a circle around the scene at ~30 degrees elevation,
each looking at the scene centre, with a small seeded jitter of radius, elevation and azimuth.
``line``: views along a straight, mostly sideways, slightly forward path in front of the scene, all
with the same orientation (a "walk past" capture); the objects drift across the frame.
Hold-out views sit halfway between two regular ones on the same path, with their own jitter, so
adding hold-out views never changes the regular ones.
Intrinsics: fx = fy = 0.9 * width, principal point at the image centre (COLMAP convention).
"""

from __future__ import annotations

import numpy as np

from recon.eval.groundtruth import Camera
from recon.synth.scene import TARGET

ORBIT_RADIUS = 3.5
ORBIT_ELEVATION_DEG = 30.0
FOCAL_FACTOR = 0.9
LINE_START = np.array([-1.5, -3.4, 2.0])
LINE_END = np.array([1.5, -2.7, 2.0])
PATHS = ("orbit", "line")


def intrinsics(width: int, height: int) -> np.ndarray:
    f = FOCAL_FACTOR * width
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at ``center`` looking at ``target`` with world z up
    (image x right, y down)."""
    forward = target - center
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return R, -R @ center


def scene_cameras(views: int = 24, width: int = 640, height: int = 480, seed: int = 0, path: str = "orbit",
                  holdout: int = 0, image_format: str = "jpg") -> tuple[dict[str, Camera], dict[str, Camera]]:
    """Regular and hold-out cameras of a synthetic scene, keyed by image name
    (``view_000.jpg``..., ``holdout_000.jpg``...), exactly as :func:`recon.synth.render_scene` uses them."""
    if path not in PATHS:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    if views < 1 or holdout < 0:
        raise ValueError("need views >= 1 and holdout >= 0")
    K = intrinsics(width, height)
    regular_s = np.arange(views, dtype=float)
    # hold-out views: halfway between regular ones, spread along the path
    holdout_s = np.floor(np.arange(holdout) * views / max(holdout, 1)) + 0.5
    if path == "line":
        holdout_s = np.minimum(holdout_s, max(views - 1.5, 0.0))
    out = []
    for stream, params in ((1, regular_s), (2, holdout_s)):
        rng = np.random.default_rng([seed, stream])
        cams = [_pose(path, s, views, rng) for s in params]
        out.append([Camera(K.copy(), R, t, width, height) for R, t in cams])
    regular = {f"view_{i:03d}.{image_format}": c for i, c in enumerate(out[0])}
    held = {f"holdout_{i:03d}.{image_format}": c for i, c in enumerate(out[1])}
    return regular, held


def _pose(path: str, s: float, views: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if path == "orbit":
        azimuth = 2 * np.pi * s / views + np.radians(rng.uniform(-1.5, 1.5))
        elevation = np.radians(ORBIT_ELEVATION_DEG + rng.uniform(-2.0, 2.0))
        radius = ORBIT_RADIUS * rng.uniform(0.96, 1.04)
        center = TARGET + radius * np.array([np.cos(elevation) * np.cos(azimuth),
                                             np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        return look_at(center, TARGET)
    frac = s / max(views - 1, 1)
    center = LINE_START + frac * (LINE_END - LINE_START) + rng.uniform(-0.03, 0.03, size=3)
    # fixed orientation: the one the middle of the path needs to look at the scene centre
    R, _ = look_at((LINE_START + LINE_END) / 2, TARGET)
    return R, -R @ center
