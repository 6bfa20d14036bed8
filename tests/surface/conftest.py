"""A small ray-cast scene for the surface tests: a ground plane with a box and a sphere, coloured by a
smooth procedural 3D pattern, seen by cameras on a ring (COLMAP convention)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from recon.eval.groundtruth import Camera
from recon.surface.raycast import cast, pixel_rays, scene_of


def scene_mesh() -> trimesh.Trimesh:
    """Ground 4 x 4 at z = 0, a box and a sphere resting on it (z up)."""
    ground = trimesh.creation.box(extents=(4.0, 4.0, 0.2))
    ground.apply_translation((0, 0, -0.1))
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.9))
    box.apply_translation((-0.7, -0.3, 0.45))
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    sphere.apply_translation((0.8, 0.5, 0.6))
    mesh = trimesh.util.concatenate([ground, box, sphere])
    return mesh.subdivide_to_size(0.15)


def colour_at(points: np.ndarray) -> np.ndarray:
    """Smooth RGB pattern in [0, 1] at world points (N, 3)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    r = 0.5 + 0.35 * np.sin(2 * np.pi * (1.3 * x + 0.4 * z)) * np.cos(2 * np.pi * 0.9 * y)
    g = 0.5 + 0.3 * np.sin(2 * np.pi * (0.7 * y - 1.1 * z) + 1.0) + 0.1 * np.sin(2 * np.pi * 3.1 * x)
    b = 0.45 + 0.25 * np.cos(2 * np.pi * (0.8 * x + 0.8 * y)) + 0.15 * np.sin(2 * np.pi * 2.3 * z + 2 * y)
    return np.clip(np.stack([r, g, b], axis=-1), 0, 1)


def ring_cameras(n: int, width: int, height: int, radius: float = 4.5, height_z: float = 2.6,
                 phase: float = 0.0) -> list[Camera]:
    f = 0.9 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    cams = []
    for i in range(n):
        a = phase + 2 * np.pi * i / n
        c = np.array([radius * np.cos(a), radius * np.sin(a), height_z + 0.3 * np.sin(3 * a)])
        fwd = np.array([0, 0, 0.3]) - c
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])
        cams.append(Camera(K, R, -R @ c, width, height))
    return cams


def render(mesh: trimesh.Trimesh, cam, width: int, height: int, gain=(1.0, 1.0, 1.0), ss: int = 3):
    """Anti-aliased colour image (uint8), depth (camera z, 0 where empty) and hit mask."""
    scene = scene_of(mesh.vertices, mesh.faces)
    o, d = pixel_rays(cam, width, height)
    hit = cast(scene, o, d)
    depth = np.where(np.isfinite(hit["t"]), hit["t"], 0.0).astype(np.float32)
    acc = np.zeros((height, width, 3))
    Kinv = np.linalg.inv(cam.K)
    for sy in range(ss):
        for sx in range(ss):
            u, v = np.meshgrid(np.arange(width) + (sx + 0.5) / ss, np.arange(height) + (sy + 0.5) / ss)
            dirs = np.stack([u, v, np.ones_like(u)], -1) @ Kinv.T @ np.asarray(cam.R)
            h = cast(scene, o, dirs)
            p = o + dirs * np.where(np.isfinite(h["t"]), h["t"], 0.0)[..., None]
            c = colour_at(p)
            c[~np.isfinite(h["t"])] = 0.0
            acc += c
    img = np.clip(acc / ss**2 * np.asarray(gain) * 255 + 0.5, 0, 255).astype(np.uint8)
    return img, depth, depth > 0


class Scene:
    """The test scene: GT mesh, cameras, photos (with per-view gains), depth maps, hold-out views."""

    def __init__(self, views: int = 12, width: int = 320, height: int = 240, gains: bool = True,
                 holdout: int = 3, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.mesh = scene_mesh()
        self.width, self.height = width, height
        self.cameras = ring_cameras(views, width, height)
        self.gains = (rng.uniform(0.75, 1.2, (views, 1)) * rng.uniform(0.93, 1.07, (views, 3))
                      if gains else np.ones((views, 3)))
        rendered = [render(self.mesh, c, width, height, g) for c, g in zip(self.cameras, self.gains)]
        self.images = [r[0] for r in rendered]
        self.depths = [r[1] for r in rendered]
        self.holdout_cameras = ring_cameras(holdout, width, height, radius=4.0, height_z=2.0, phase=0.4)
        held = [render(self.mesh, c, width, height) for c in self.holdout_cameras]
        self.holdout_images = [r[0] for r in held]
        self.holdout_masks = [r[2] for r in held]
        self.extent = float(np.linalg.norm(self.mesh.bounds[1] - self.mesh.bounds[0]))

    def fused_points(self, noise: float = 0.0, seed: int = 0):
        """Points and normals from back-projecting the depth maps (as fusion would give)."""
        rng = np.random.default_rng(seed)
        scene = scene_of(self.mesh.vertices, self.mesh.faces)
        pts, nrm = [], []
        for cam in self.cameras:
            o, d = pixel_rays(cam, self.width, self.height)
            h = cast(scene, o[::2, ::2], d[::2, ::2])
            ok = h["face"] >= 0
            p = o[::2, ::2][ok] + d[::2, ::2][ok] * h["t"][ok][:, None]
            n = self.mesh.face_normals[h["face"][ok]]
            pts.append(p + rng.normal(0, noise, p.shape) if noise else p)
            nrm.append(n)
        return np.concatenate(pts), np.concatenate(nrm)


@pytest.fixture(scope="session")
def small_scene() -> Scene:
    return Scene()
