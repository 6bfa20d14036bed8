"""Texture quality: render textured or vertex-coloured meshes into cameras, masked PSNR, seam colour jumps.

Rendering casts one ray per pixel centre (open3d RaycastingScene), interpolates the hit face's corner
texture coordinates (or vertex colours) barycentrically and looks the atlas up bilinearly: what a viewer
shows without mip-mapping.
"""

from __future__ import annotations

import numpy as np
import trimesh

from recon.imaging.pixels import sample_bilinear
from recon.surface.raycast import cast, pixel_rays, scene_of
from recon.surface.texture import TexturedMesh
from recon.surface.texture.topology import face_adjacency


def _as_arrays(mesh: trimesh.Trimesh | TexturedMesh):
    """(vertices, faces, corner uv or None, texture or None, vertex colours or None) of either mesh kind."""
    if isinstance(mesh, TexturedMesh):
        return mesh.vertices, mesh.faces, mesh.uv, mesh.texture, mesh.vertex_colors
    faces = np.asarray(mesh.faces)
    if mesh.visual.kind == "texture" and mesh.visual.uv is not None:
        mat = mesh.visual.material
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        if image is None:
            raise ValueError("the mesh's material has no texture image")
        texture = np.asarray(image.convert("RGB"))
        return np.asarray(mesh.vertices), faces, np.asarray(mesh.visual.uv)[faces], texture, None
    return np.asarray(mesh.vertices), faces, None, None, np.asarray(mesh.visual.vertex_colors)[:, :3]


def render(mesh: trimesh.Trimesh | TexturedMesh, cam, width: int, height: int,
           vertex_colors: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Image (H, W, 3; float 0-255) and coverage mask of ``mesh`` seen by ``cam`` (K, R, t); with
    ``vertex_colors`` a TexturedMesh is drawn from its vertex colours instead of its texture."""
    return render_rays(mesh, *pixel_rays(cam, width, height), vertex_colors)


def render_rays(mesh: trimesh.Trimesh | TexturedMesh, origins: np.ndarray, directions: np.ndarray,
                vertex_colors: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`render` along given rays (H, W, 3 origins and directions): for cameras with distortion."""
    vertices, faces, uv, texture, vcolor = _as_arrays(mesh)
    hit = cast(scene_of(vertices, faces), origins, directions)
    mask = hit["face"] >= 0
    f = hit["face"][mask]
    b = hit["bary"][mask]
    image = np.zeros((*mask.shape, 3), np.float32)
    if uv is not None and not vertex_colors:
        p = np.einsum("nk,nkc->nc", b, uv[f])
        th, tw = texture.shape[:2]
        image[mask] = sample_bilinear(texture[..., :3], p[:, 0] * tw, (1 - p[:, 1]) * th)
    else:
        image[mask] = np.einsum("nk,nkc->nc", b, np.asarray(vcolor, np.float32)[faces[f]])
    return image, mask


def first_hits(mesh: trimesh.Trimesh | TexturedMesh, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Per ray (origins and directions H, W, 3), where the mesh's first hit lies along it, in units of the
    direction's length (inf on a miss): with camera-frame directions of z = 1, the depth the mesh shows
    at each pixel."""
    vertices, faces, *_ = _as_arrays(mesh)
    return cast(scene_of(vertices, faces), origins, directions)["t"]


def masked_psnr(rendered: np.ndarray, gt_image: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, peak 255) over the pixels where ``mask`` is set."""
    diff = np.asarray(rendered, np.float64)[mask] - np.asarray(gt_image, np.float64)[mask]
    mse = float(np.mean(diff**2)) if diff.size else 0.0
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def seam_jump(mesh: trimesh.Trimesh | TexturedMesh, samples: int = 8, offset: float = 0.0) -> float:
    """Mean absolute colour difference (0-255, over RGB) across texture seams: on every mesh edge whose two
    faces map it to different atlas places, ``samples`` points along the edge are looked up in each face's
    chart (``offset`` texels inside the face; at 0 both lookups show the same surface point, so the texture's
    own gradient does not count); edges weigh by their length. On a TexturedMesh
    only borders between photo patches count (faces seen by no photo are left out)."""
    vertices, faces, uv, texture, _ = _as_arrays(mesh)
    if uv is None:
        raise ValueError("seam_jump needs a textured mesh")
    # faces of a loaded mesh are split along UV seams: join them by vertex position
    positions, geo = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    gfaces = geo.ravel()[faces]
    pairs, ev = face_adjacency(gfaces)
    th, tw = texture.shape[:2]
    px = uv * [tw, th]
    px[..., 1] = th - px[..., 1]

    def corner(face, v):
        slot = np.argmax(gfaces[face] == v[:, None], axis=1)
        return px[face, slot]

    a0, a1 = corner(pairs[:, 0], ev[:, 0]), corner(pairs[:, 0], ev[:, 1])
    b0, b1 = corner(pairs[:, 1], ev[:, 0]), corner(pairs[:, 1], ev[:, 1])
    seam = (np.abs(a0 - b0).max(1) > 1e-3) | (np.abs(a1 - b1).max(1) > 1e-3)
    if isinstance(mesh, TexturedMesh):
        seam &= np.all(mesh.face_view[pairs] >= 0, axis=1)
    if not seam.any():
        return 0.0
    pairs, ev, a0, a1, b0, b1 = pairs[seam], ev[seam], a0[seam], a1[seam], b0[seam], b1[seam]
    t = ((np.arange(samples) + 0.5) / samples)[None, :, None]
    values = []
    for face, p0, p1 in ((pairs[:, 0], a0, a1), (pairs[:, 1], b0, b1)):
        p = p0[:, None] * (1 - t) + p1[:, None] * t
        towards = px[face].mean(axis=1)[:, None] - p
        dist = np.linalg.norm(towards, axis=-1, keepdims=True)
        p = p + towards / np.maximum(dist, 1e-9) * np.minimum(dist, offset)
        values.append(sample_bilinear(texture[..., :3], p[..., 0], p[..., 1]))
    jump = np.abs(values[0] - values[1]).mean(axis=(1, 2))
    length = np.linalg.norm(positions[ev[:, 1]] - positions[ev[:, 0]], axis=1)
    return float(np.sum(jump * length) / max(length.sum(), 1e-30))

