"""Test helpers: points on the synthetic scene's true surface and where the photos see them, for scale
bars and ground control points with known truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pyproj import Transformer

from recon.geometry.gps import wgs84_from_enu
from recon.geometry.transforms import Similarity, backproject
from recon.synth import load_scene

METRES_PER_UNIT = 10.0  # the 3.5-unit orbit becomes 35 m
ORIGIN = (47.3769, 8.5417, 430.0)  # Zurich: UTM zone 32N
UTM_32N = "EPSG:32632"


def true_enu() -> Similarity:
    """The scene's world frame -> ENU metres at ORIGIN."""
    yaw = np.radians(30.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return Similarity(METRES_PER_UNIT, R, np.array([50.0, -20.0, 5.0]))


@dataclass(frozen=True, eq=False)
class MarkedPoint:
    world: np.ndarray  # (3,) in the scene's world frame
    pixels: dict[str, np.ndarray]  # photo -> (x, y), the top-left pixel's centre at (0, 0) (as users click)


def marked_points(scene_dir, count: int, *, min_views: int = 3, max_views: int = 4, noise_px: float = 0.0,
                  seed: int = 0, spread: float = 0.0) -> list[MarkedPoint]:
    """``count`` points of the true surface, each seen (unoccluded) by at least ``min_views`` photos,
    with their pixel positions in up to ``max_views`` of them plus N(0, ``noise_px``) noise. Points are
    at least ``spread`` apart."""
    scene = load_scene(scene_dir)
    cameras = scene.cameras()
    names = sorted(cameras)
    depths = {n: scene.depth(n) for n in names}
    rng = np.random.default_rng(seed)
    found: list[MarkedPoint] = []
    for _ in range(2000):
        if len(found) == count:
            break
        source = names[rng.integers(len(names))]
        cam, depth = cameras[source], depths[source]
        row, col = rng.integers(20, cam.height - 20), rng.integers(20, cam.width - 20)
        if depth[row, col] <= 0:
            continue
        world = backproject(cam.K, cam.R, cam.t, [[col + 0.5, row + 0.5]], [depth[row, col]])[0]
        if any(np.linalg.norm(world - p.world) < spread for p in found):
            continue
        seen = {}
        for name in names:
            uv, z = cameras[name].project(world[None])
            x, y = uv[0]
            if z[0] <= 0 or not (5 <= x < cam.width - 5 and 5 <= y < cam.height - 5):
                continue
            if abs(depths[name][int(y), int(x)] - z[0]) > 0.005 * z[0]:
                continue  # hidden behind something
            seen[name] = uv[0] - 0.5 + rng.normal(0, noise_px, 2) if noise_px else uv[0] - 0.5
        if len(seen) >= min_views:
            chosen = rng.choice(sorted(seen), min(max_views, len(seen)), replace=False)
            found.append(MarkedPoint(world, {str(n): seen[n] for n in sorted(chosen)}))
    assert len(found) == count, "the scene shows too few such points"
    return found


def write_gcp_list(path, points, *, crs: str = UTM_32N, offsets: dict | None = None, names=None) -> dict:
    """An ODM gcp_list.txt of ``points`` (MarkedPoint) at their true positions (plus ``offsets``,
    metres ENU, per index), in ``crs`` (UTM 32N, or ENU); returns name -> true ENU at ORIGIN."""
    truth, offsets = true_enu(), offsets or {}
    lines, enu = [crs], {}
    to_utm = Transformer.from_crs("EPSG:4979", crs, always_xy=True) if crs != "ENU" else None
    for k, point in enumerate(points):
        name = names[k] if names else f"gcp_{k}"
        enu[name] = truth.apply(point.world)
        surveyed = enu[name] + np.asarray(offsets.get(k, np.zeros(3)))
        if to_utm is None:
            xyz = surveyed
        else:
            lat, lon, h = wgs84_from_enu(surveyed, ORIGIN)[0]
            xyz = to_utm.transform(lon, lat, h)
        for photo, (x, y) in point.pixels.items():
            lines.append(f"{xyz[0]:.4f} {xyz[1]:.4f} {xyz[2]:.4f} {x:.2f} {y:.2f} {photo} {name}")
    path.write_text("\n".join(lines) + "\n")
    return enu
