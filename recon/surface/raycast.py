"""Ray casting against a triangle mesh with open3d's RaycastingScene (CPU, Embree)."""

from __future__ import annotations

import numpy as np

from recon._open3d import open3d
from recon.geometry.transforms import apply_matrix, camera_center, project


def scene_of(vertices: np.ndarray, faces: np.ndarray):
    """A RaycastingScene holding one triangle mesh; primitive ids are face indices."""
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    return scene


def cast(scene, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
    """First hits of rays: ``t`` (inf on a miss, in units of the direction's length), ``face`` (-1 on a
    miss) and ``bary`` (N, 3) barycentric coordinates of the hit on its face's three vertices."""
    o3d = open3d()
    shape = origins.shape[:-1]
    rays = np.concatenate([origins, directions], axis=-1).reshape(-1, 6).astype(np.float32)
    out = scene.cast_rays(o3d.core.Tensor(rays))
    t = out["t_hit"].numpy().reshape(shape)
    face = out["primitive_ids"].numpy().astype(np.int64).reshape(shape)
    face[~np.isfinite(t)] = -1
    uv = out["primitive_uvs"].numpy().reshape(*shape, 2)
    bary = np.concatenate([1.0 - uv.sum(-1, keepdims=True), uv], axis=-1)
    return {"t": t, "face": face, "bary": bary}


def pixel_rays(cam, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions (H, W, 3) of rays through every pixel centre; a direction has camera z = 1,
    so the hit distance ``t`` is the depth."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    d = apply_matrix(np.asarray(cam.R, float).T, apply_matrix(np.linalg.inv(np.asarray(cam.K, float)), pix))
    o = np.broadcast_to(camera_center(cam.R, cam.t), d.shape)
    return o, d


def render_ids(scene, cam, width: int, height: int) -> dict[str, np.ndarray]:
    """Per pixel: depth (camera z, inf where empty), face id (-1 where empty) and barycentrics."""
    o, d = pixel_rays(cam, width, height)
    hit = cast(scene, o, d)
    return {"depth": hit["t"], "face": hit["face"], "bary": hit["bary"]}


#: views are ray cast at most this size (longest side, px) to decide what they see
VISIBILITY_SIZE = 800


def cast_size(view) -> tuple[int, int]:
    """(width, height) at which ``view`` is ray cast: at most ``VISIBILITY_SIZE`` px on its longer side."""
    scale = min(1.0, VISIBILITY_SIZE / max(view.width, view.height))
    return max(1, round(view.width * scale)), max(1, round(view.height * scale))


def points_in_view(scene, view, points: np.ndarray) -> dict:
    """Where each of ``points`` (N, 3) lies in ``view`` (a camera with K, R, t, width, height), ray cast
    at most ``VISIBILITY_SIZE`` px: ``inside`` (in front of the camera, within the frame), ``row`` and
    ``col`` (pixel at the cast size; valid where inside), ``z`` (the point's depth) and ``first`` (the
    depth of the view's first hit at that pixel: the mesh's nearest surface there; inf where empty): arrays
    (N,); and ``width`` and ``height``, the cast size."""
    from recon.mvs.views import scaled_to

    width, height = cast_size(view)
    cam = scaled_to(view, width, height)
    depth = render_ids(scene, cam, width, height)["depth"]
    uv, z = project(cam.K, cam.R, cam.t, points)
    front = z > 0
    cols = np.floor(np.where(front, uv[:, 0], -1)).astype(np.int64)
    rows = np.floor(np.where(front, uv[:, 1], -1)).astype(np.int64)
    inside = front & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    rows, cols = np.where(inside, rows, 0), np.where(inside, cols, 0)
    return {"inside": inside, "row": rows, "col": cols, "z": z, "first": depth[rows, cols],
            "width": width, "height": height}
