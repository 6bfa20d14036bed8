"""Ray-cast rendering of the synthetic scene: colour image, ground-truth depth and normals.

One ray per pixel centre (open3d's RaycastingScene) gives depth, normals and colour. Pixels whose
3x3 neighbourhood crosses a silhouette or a crease (another part, or a depth jump) are re-cast with
``supersample`` x ``supersample`` rays and averaged: geometric anti-aliasing where it is needed.
Texture anti-aliasing is done by trilinear mip-mapping (see textures.py), which filters over the
sample's footprint on the surface.

Shading is Lambertian with a fixed directional light plus ambient, no shadows: a surface point has
the same colour from every view, so photo-consistency holds exactly up to resampling, texture
filtering and JPEG. A glossy part (``Part.gloss`` > 0) adds a white Blinn-Phong highlight, which
moves over its surface from view to view as a glaze's or a car's does. Rays that miss get the
background (a uniform sky colour by default; any colour, or a colour per world ray direction such as
:func:`gradient_sky`) and depth 0.

Ray directions are ``R^T K^-1 (u, v, 1)`` (with the lens's distortion undone, :meth:`recon.eval.
groundtruth.Camera.rays`), unnormalised, so the hit parameter is the camera z.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from recon._open3d import open3d
from recon.eval.groundtruth import Camera
from recon.geometry.transforms import apply_matrix
from recon.synth.scene import Scene
from recon.synth.textures import sample

LIGHT = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])
AMBIENT = 0.42
DIFFUSE = 0.62
SKY = np.array([0.77, 0.82, 0.89], np.float32)
DEPTH_JUMP = 0.03  # relative depth change between neighbours that counts as an occlusion edge
SHININESS = 20.0  # Blinn-Phong exponent of a glossy part's highlight


def gradient_sky(dirs: np.ndarray) -> np.ndarray:
    """A clear sky (N, 3 RGB in [0, 1]) by world ray direction (N, 3, z up): pale at the horizon,
    deeper blue towards the zenith, greyish below the horizon. It lies at infinity, so a sky point
    looks the same from every camera, as the real sky does."""
    z = dirs[:, 2] / np.linalg.norm(dirs, axis=1)
    up = np.clip(z, 0.0, 1.0)[:, None] ** 0.6
    horizon, zenith, below = (np.array(c, np.float32) for c in ((0.86, 0.89, 0.93), (0.36, 0.55, 0.84),
                                                                 (0.62, 0.64, 0.66)))
    sky = horizon + (zenith - horizon) * up
    return np.where(z[:, None] >= 0, sky, below).astype(np.float32)


Background = np.ndarray | Callable[[np.ndarray], np.ndarray]


class Renderer:
    """Renders views of one :class:`~recon.synth.scene.Scene` in front of ``background``: an RGB colour
    in [0, 1] or a function of world ray directions (N, 3) giving colours (N, 3)."""

    def __init__(self, scene: Scene, background: Background = SKY):
        o3d = open3d()
        self.scene = scene
        self.background = background
        self._rays = o3d.t.geometry.RaycastingScene()
        self._rays.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                                 o3d.core.Tensor(scene.faces.astype(np.uint32)))
        # per triangle: uv0, uv1-uv0, uv2-uv0, n0, n1-n0, n2-n0 packed in one row, so a hit needs a
        # single gather: attribute = a0 + b1 * d1 + b2 * d2 with (b1, b2) open3d's barycentrics
        uv, nv = scene.uv[scene.faces], scene.normals[scene.faces]
        self._face_attr = np.concatenate([uv[:, 0], uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0],
                                          nv[:, 0], nv[:, 1] - nv[:, 0], nv[:, 2] - nv[:, 0]], 1).astype(np.float32)
        self._density = np.array([p.texels_per_unit for p in scene.parts])
        self._gloss = np.array([p.gloss for p in scene.parts], np.float32)
        self._grids: dict[tuple, np.ndarray] = {}

    def render(self, cam: Camera, supersample: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(RGB uint8 HxWx3, depth float32 HxW (camera z, 0 = sky), normals float32 HxWx3 in the camera
        frame facing it, 0 = sky) of camera ``cam``."""
        key = (cam.width, cam.height, cam.K.tobytes(), cam.radial)
        if key not in self._grids:  # pixel-centre rays depend on the intrinsics only
            self._grids[key] = _camera_rays(cam, _pixel_centres(cam))
        return self.render_rays(cam.center, cam.R, cam.width, cam.height, lambda px: _camera_rays(cam, px),
                                cam.K[0, 0], supersample, self._grids[key])

    def render_rays(self, center: np.ndarray, R: np.ndarray, width: int, height: int,
                    rays: Callable[[np.ndarray], np.ndarray], pixels_per_radian: float, supersample: int = 3,
                    centre_rays: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render a camera of any projection: ``rays`` maps pixel positions (N, 2, COLMAP convention)
        to camera-frame ray directions (N, 3); ``pixels_per_radian`` (the focal length of a pinhole)
        sets the texture filter. The depth map holds each pixel ray's hit parameter: camera z for
        rays with z = 1 (as :meth:`render` casts), the distance for unit rays. ``centre_rays``: the
        pixel centres' rays, when already known."""
        w, h = width, height
        if centre_rays is None:
            jj, ii = np.meshgrid(np.arange(w, dtype=np.float32) + 0.5, np.arange(h, dtype=np.float32) + 0.5)
            centre_rays = rays(np.column_stack([jj.ravel(), ii.ravel()]))
        dirs_cam = centre_rays
        hit = self._cast(center, R, dirs_cam, 1.0, pixels_per_radian)
        idx = hit["idx"]

        depth = np.zeros(h * w, np.float32)
        depth[idx] = hit["t"]
        normal = np.zeros((h * w, 3), np.float32)
        n_cam = apply_matrix(R.astype(np.float32), hit["normals"])
        n_cam[np.einsum("ij,ij->i", n_cam, dirs_cam[idx]) > 0] *= -1
        normal[idx] = n_cam
        colour = self._background(R, dirs_cam)
        colour[idx] = hit["colour"]
        part = np.full(h * w, -1, np.int32)
        part[idx] = hit["part"]
        depth, normal, colour = depth.reshape(h, w), normal.reshape(h, w, 3), colour.reshape(h, w, 3)

        edges = edge_pixels(part.reshape(h, w), depth)
        if supersample > 1 and edges.any():
            ei, ej = np.nonzero(edges)
            offs = (np.arange(supersample, dtype=np.float32) + 0.5) / supersample
            oy, ox = np.meshgrid(offs, offs, indexing="ij")
            px = np.stack([ej[:, None] + ox.ravel()[None], ei[:, None] + oy.ravel()[None]], -1).reshape(-1, 2)
            sub_dirs = rays(px)
            sub = self._cast(center, R, sub_dirs, 1.0 / supersample, pixels_per_radian)
            sub_col = self._background(R, sub_dirs)
            sub_col[sub["idx"]] = sub["colour"]
            colour[ei, ej] = sub_col.reshape(len(ei), -1, 3).mean(1)
        rgb = np.clip(colour * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return rgb, depth, normal

    def part_ids(self, cam: Camera) -> np.ndarray:
        """Index into ``scene.parts`` of the surface each pixel centre sees (HxW int32, -1 = none)."""
        o3d = open3d()
        rays = np.empty((cam.width * cam.height, 6), np.float32)
        rays[:, :3] = cam.center
        rays[:, 3:] = apply_matrix(cam.R.T.astype(np.float32), _camera_rays(cam, _pixel_centres(cam)))
        prim = self._rays.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().astype(np.int64)
        hit = prim != o3d.t.geometry.RaycastingScene.INVALID_ID
        ids = np.full(len(prim), -1, np.int32)
        ids[hit] = self.scene.face_part[prim[hit]]
        return ids.reshape(cam.height, cam.width)

    def _background(self, R: np.ndarray, dirs_cam: np.ndarray) -> np.ndarray:
        """Background colours (N, 3) of camera-frame rays ``dirs_cam`` of a camera with rotation ``R``."""
        return background_colours(self.background, apply_matrix(R.T.astype(np.float32), dirs_cam))

    def _cast(self, center: np.ndarray, R: np.ndarray, dirs_cam: np.ndarray, sample_pixels: float,
              pixels_per_radian: float) -> dict[str, np.ndarray]:
        """Cast rays with camera-frame directions ``dirs_cam`` (N, 3; z = 1, or unit) from ``center``
        (world-to-camera rotation ``R``) and shade the hits. ``sample_pixels`` is the sample spacing
        in pixels of ``pixels_per_radian`` (sets the texture filter footprint).
        Returns, for the rays that hit (indices ``idx``): depth ``t``, ``part``, world ``normals``
        and ``colour``."""
        o3d = open3d()
        rays = np.empty((len(dirs_cam), 6), np.float32)
        rays[:, :3] = center
        rays[:, 3:] = apply_matrix(R.T.astype(np.float32), dirs_cam)
        res = self._rays.cast_rays(o3d.core.Tensor(rays))
        t = res["t_hit"].numpy()
        idx = np.flatnonzero(np.isfinite(t))
        t = t[idx]
        prim = res["primitive_ids"].numpy()[idx].astype(np.int64)
        bary = res["primitive_uvs"].numpy()[idx]
        b1, b2 = bary[:, 0:1], bary[:, 1:2]
        a = self._face_attr[prim]
        uv = a[:, 0:2] + b1 * a[:, 2:4] + b2 * a[:, 4:6]
        n = a[:, 6:9] + b1 * a[:, 9:12] + b2 * a[:, 12:15]
        n *= (1.0 / np.sqrt(np.einsum("ij,ij->i", n, n)))[:, None]
        d = rays[idx, 3:]
        cos = np.abs(np.einsum("ij,ij->i", n, d)) / np.sqrt(np.einsum("ij,ij->i", d, d))
        # world size of one sample on the surface: t x the sample's angle, stretched on oblique
        # surfaces (geometric mean of the two axes' stretch: between blurring and aliasing)
        footprint = t * np.float32(sample_pixels / pixels_per_radian) / np.sqrt(np.maximum(cos, 0.05))
        part = self.scene.face_part[prim]
        albedo = np.empty((len(idx), 3), np.float32)
        for k in np.unique(part):
            sel = np.flatnonzero(part == k)
            level = np.log2(np.maximum(footprint[sel] * self._density[k], 1e-6))
            albedo[sel] = sample(self.scene.parts[k].texture, uv[sel], level)
        lit = n[:, 0] * LIGHT[0] + n[:, 1] * LIGHT[1] + n[:, 2] * LIGHT[2]
        colour = albedo * (AMBIENT + DIFFUSE * np.maximum(lit, 0.0))[:, None].astype(np.float32)
        gloss = self._gloss[part]
        if gloss.any():
            half = LIGHT - d / np.linalg.norm(d, axis=1, keepdims=True)  # light + view direction
            half /= np.linalg.norm(half, axis=1, keepdims=True)
            facing = np.maximum(np.einsum("ij,ij->i", n, half), 0.0) * (lit > 0)
            colour += (gloss * facing**SHININESS)[:, None].astype(np.float32)
        return {"idx": idx, "t": t, "part": part, "normals": n, "colour": colour}


def _pixel_centres(cam: Camera) -> np.ndarray:
    """The pixel centres (W*H, 2; row after row) of ``cam``'s image."""
    jj, ii = np.meshgrid(np.arange(cam.width, dtype=np.float32) + 0.5, np.arange(cam.height, dtype=np.float32) + 0.5)
    return np.column_stack([jj.ravel(), ii.ravel()])


def _camera_rays(cam: Camera, px: np.ndarray) -> np.ndarray:
    """Camera-frame ray directions (z = 1, so a hit's parameter is its depth) of pixel positions ``px``."""
    return cam.rays(px).astype(np.float32)


def background_colours(background: Background, directions: np.ndarray) -> np.ndarray:
    """What rays of world ``directions`` (N, 3) that miss the scene show (N, 3 RGB in [0, 1])."""
    if callable(background):
        return background(np.asarray(directions, np.float32))
    return np.tile(np.asarray(background, np.float32), (len(directions), 1))


def edge_pixels(part: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Pixels whose 8-neighbourhood holds another part (or sky) or a relative depth jump."""
    h, w = part.shape
    pp = np.pad(part, 1, mode="edge")
    dp = np.pad(depth, 1, mode="edge")
    edges = np.zeros((h, w), bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            if dy == 1 and dx == 1:
                continue
            nb_part = pp[dy : dy + h, dx : dx + w]
            nb_depth = dp[dy : dy + h, dx : dx + w]
            edges |= nb_part != part
            edges |= np.abs(nb_depth - depth) > DEPTH_JUMP * np.maximum(depth, nb_depth)
    return edges
