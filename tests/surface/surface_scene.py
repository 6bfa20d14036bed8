"""The surface tests' scene: photos, cameras, ground-truth depth, oriented points and hold-out views
(a module of its own, not conftest: test folders each have a conftest, so `from conftest import` is
ambiguous)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from PIL import Image

from recon.geometry.transforms import backproject
from recon.synth import SceneInfo


@dataclass
class Scene:
    info: SceneInfo
    images: list[np.ndarray]
    cameras: list
    depths: list[np.ndarray]
    holdout_images: list[np.ndarray]
    holdout_cameras: list
    gt_mesh: trimesh.Trimesh

    def points(self, step: int = 1):
        """Oriented, coloured points back-projected from the ground-truth depth and normal maps."""
        pts, nrm, col = [], [], []
        for name, cam, img, depth in zip(self.info.image_names, self.cameras, self.images, self.depths, strict=True):
            d = depth[::step, ::step]
            ok = d > 0
            h, w = depth.shape
            u, v = np.meshgrid(np.arange(0, w, step) + 0.5, np.arange(0, h, step) + 0.5)
            pts.append(backproject(cam.K, cam.R, cam.t, np.stack([u[ok], v[ok]], 1), d[ok]))
            nrm.append(self.info.normal(name)[::step, ::step][ok] @ cam.R)
            col.append(img[::step, ::step][ok])
        return np.concatenate(pts), np.concatenate(nrm), np.concatenate(col)


def with_gains(images: list[np.ndarray], seed: int = 1) -> list[np.ndarray]:
    """The photos with a different exposure gain and white balance each, as real cameras give."""
    rng = np.random.default_rng(seed)
    gains = rng.uniform(0.75, 1.2, (len(images), 1)) * rng.uniform(0.93, 1.07, (len(images), 3))
    return [np.clip(im * g + 0.5, 0, 255).astype(np.uint8) for im, g in zip(images, gains, strict=True)]


def load_arrays(info: SceneInfo) -> Scene:
    def read(folder, names):
        return [np.asarray(Image.open(folder / n).convert("RGB")) for n in names]

    cams, held = info.cameras(), info.cameras(holdout=True)
    return Scene(info, read(info.images_dir, info.image_names), [cams[n] for n in info.image_names],
                 [info.depth(n) for n in info.image_names], read(info.holdout_images_dir, info.holdout_names),
                 [held[n] for n in info.holdout_names], trimesh.load(info.mesh_path, process=False))


def sphere_points(n: int) -> np.ndarray:
    """``n`` points spread evenly over the unit sphere (a Fibonacci lattice); each is its own normal."""
    k = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * k / n), np.pi * (1 + 5**0.5) * k
    return np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])
