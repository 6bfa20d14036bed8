"""Texture mapping of a mesh from its photos (after Waechter et al. 2014, "Let There Be Color!").

Steps: per-face view quality with occlusion tests (:mod:`.views`), the photos' exposure, white balance
and vignetting evened out (:mod:`.photometric`), views inconsistent with the others dropped per face
(:mod:`.consistency`), one view per face by graph cuts
(:mod:`.selection`), global seam levelling if asked for (:mod:`.levelling`), an atlas of the patches' projections
(:mod:`.atlas`), baking (:mod:`.bake`: each texel the chosen photo's colour averaged with the other photos that see
it nearly as well), local blending along seams (:mod:`.blending`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np
import trimesh

from recon.imaging.masks import mask_at
from recon.surface.options import TextureOptions
from recon.surface.raycast import render_ids, scene_of
from recon.surface.texture.atlas import layout
from recon.surface.texture.bake import Mixing, bake, vertex_colors
from recon.surface.texture.blending import blend_seams
from recon.surface.texture.consistency import drop_inconsistent_views
from recon.surface.texture.levelling import level_seams
from recon.surface.texture.model import TexturedMesh
from recon.surface.texture.photometric import calibrate_photos
from recon.surface.texture.selection import select_views
from recon.surface.texture.topology import face_adjacency, patches
from recon.surface.texture.views import view_quality

log = logging.getLogger(__name__)

__all__ = ["TexturedMesh", "texture_mesh"]


def texture_mesh(mesh: trimesh.Trimesh, images: Sequence[np.ndarray], cameras: Sequence,
                 options: TextureOptions = TextureOptions(),
                 masks: Sequence[np.ndarray | None] | None = None) -> TexturedMesh:
    """Texture ``mesh`` from undistorted photos (H x W x 3 uint8 RGB) taken by ``cameras`` (objects with
    K, R, t in the COLMAP convention). ``masks`` (per photo, True = the subject, or None): a masked
    pixel is treated as an occluder in front of everything, so no face takes a colour from it."""
    clock = time.perf_counter()
    timings = {}

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        timings[name] = now - clock
        clock = now

    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    photos = [np.asarray(im, np.float32) for im in images]
    scene = scene_of(vertices, faces)
    depths = [render_ids(scene, cam, im.shape[1], im.shape[0])["depth"] for cam, im in zip(cameras, images, strict=True)]
    for depth, mask in zip(depths, masks or [], strict=False):
        if mask is not None:
            depth[~mask_at(mask, depth.shape[1], depth.shape[0])] = 0.0
    lap("depth maps")
    quality = view_quality(vertices, faces, images, cameras, depths, options.min_view_cosine,
                           options.border_margin)
    lap("visibility")
    if options.colour_calibration:
        calibration = calibrate_photos(quality, vertices, faces, images, cameras)
        photos = [calibration.apply(j, photo, cam) for j, (photo, cam) in enumerate(zip(photos, cameras, strict=True))]
        lap("colour calibration")
    if options.photo_consistency:
        quality = drop_inconsistent_views(quality, vertices, faces, photos, cameras)
        lap("photo-consistency")
    pairs, edge_vertices = face_adjacency(faces)
    edge_length = np.linalg.norm(vertices[edge_vertices[:, 0]] - vertices[edge_vertices[:, 1]], axis=1)
    area = np.asarray(trimesh.triangles.area(vertices[faces]))
    labels = select_views(quality, pairs, area, edge_length, options.smoothness, options.expansion_cycles)
    patch = patches(labels, pairs)
    lap("selection")
    if options.levelling:
        corner_corr = level_seams(vertices, faces, labels, patch, pairs, edge_vertices, photos, cameras, depths,
                                  options.levelling_weight)
    else:
        corner_corr = np.zeros((len(faces), 3, 3), np.float32)
    lap("levelling")
    vcolor = vertex_colors(vertices, faces, labels, corner_corr, photos, cameras)
    lay = layout(vertices, faces, labels, patch, cameras, options.max_texture_size, options.texel_scale,
                 options.padding)
    # levelling's corrections are fitted to the chosen photos' colours along the seams, not to mixtures
    mixing = Mixing(vertices, quality, cameras, options.mix_ratio) \
        if options.mix_ratio > 0 and not options.levelling else None
    atlas = bake(lay, faces, labels, corner_corr, vcolor, photos, depths, mixing)
    lap("bake")
    if options.seam_blending:
        atlas = blend_seams(atlas, lay, vertices, faces, labels, patch, pairs, edge_vertices, cameras, depths,
                            options.blend_band)
        lap("blending")
    uv = np.stack([lay.corner_xy[..., 0] / lay.width, 1.0 - lay.corner_xy[..., 1] / lay.height], axis=-1)
    log.info("textured %d faces (%d unseen) from %d views into %d patches, atlas %d x %d; %s", len(faces),
             int((labels < 0).sum()), len(images), int(len(np.unique(patch[labels >= 0]))), lay.width,
             lay.height, ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    return TexturedMesh(vertices, faces, uv, np.round(atlas).astype(np.uint8), labels,
                        np.round(vcolor).astype(np.uint8))
