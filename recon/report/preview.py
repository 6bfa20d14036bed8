"""A copy of the textured model small enough for the report page, whatever the size of textured.glb.

The surface is welded (the glTF splits vertices along texture seams), decimated by quadric edge
collapse (:func:`recon.surface.cleanup.decimate`) and charted afresh by xatlas; its texture is baked
from textured.glb's atlas at the nearest point of the full surface (open3d's closest-point query),
at most ``texture`` texels a side and about as many texels in charts as the source atlas has (a larger
copy shows no more detail and costs bake time: 2048 x 1951 texels baked from an 884 x 884 atlas took 5 of the
report's 14 s), and stored as JPEG. The copy stays in textured.glb's frame.
"""

from __future__ import annotations

import io
import logging

import numpy as np

log = logging.getLogger(__name__)

#: the copy's atlas side over the source's (sqrt of its texels): xatlas fills about 67 % of an atlas
_PADDED = 1.25


def page_model(glb: bytes, max_faces: int, texture: int) -> bytes:
    """A GLB of at most ``max_faces`` faces with a JPEG texture of at most ``texture`` texels a side,
    showing what the textured GLB ``glb`` shows."""
    import trimesh

    from recon.surface.cleanup import decimate

    full = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    welded = trimesh.Trimesh(full.vertices, full.faces, process=False)
    welded.merge_vertices()
    small = decimate(welded, max_faces)
    source_material = getattr(full.visual, "material", None)
    image = getattr(source_material, "baseColorTexture", None)
    if full.visual.kind != "texture" or image is None:  # nothing to bake: the geometry alone
        return small.export(file_type="glb")
    source_image = np.asarray(image.convert("RGB"))
    side = min(texture, int(_PADDED * np.sqrt(source_image.shape[0] * source_image.shape[1])))
    vertices, faces, uv, size = _charts(np.asarray(small.vertices), np.asarray(small.faces), side)
    atlas = _bake(vertices, faces, uv, size, full, source_image)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=_jpeg(atlas), metallicFactor=0.0,
                                                   roughnessFactor=1.0,
                                                   doubleSided=bool(getattr(source_material, "doubleSided", False)))
    out = trimesh.Trimesh(vertices, faces, visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
                          process=False)
    data = out.export(file_type="glb")
    log.info("report: textured model %.1f MB, %d faces -> page copy %.1f MB, %d faces, %d x %d texture",
             len(glb) / 1e6, len(full.faces), len(data) / 1e6, len(faces), atlas.shape[1], atlas.shape[0])
    return data


def _charts(vertices: np.ndarray, faces: np.ndarray, texture: int):
    """xatlas charts packed for a ``texture``-texel atlas: vertices (split at seams), faces, UVs
    (trimesh's convention: v up) and the atlas' (width, height), at most ``texture``."""
    import trimesh
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.uint32))
    charts = xatlas.ChartOptions()
    charts.max_iterations = 0  # grown once: on 30,000 faces 6.4 s, not 16.6 s; 67 % of the atlas used, not 72 %
    # no chart over 2 % of the surface: on a 30,000-face zoo copy 422 charts, not 389, in 0.9 s, not 2.5 s
    # (xatlas' cost grows with the charts' size); 60 % of the atlas used, not 62 %
    charts.max_chart_area = float(trimesh.triangles.area(vertices[faces]).sum()) / 50
    pack = xatlas.PackOptions()
    pack.resolution = texture
    pack.padding = 2
    atlas.generate(charts, pack)
    mapping, indices, uv = atlas.get_mesh(0)
    scale = min(1.0, texture / max(atlas.width, atlas.height, 1))  # xatlas may exceed the resolution asked
    size = (max(int(atlas.width * scale), 1), max(int(atlas.height * scale), 1))
    return vertices[mapping], indices.astype(np.int64), uv.astype(np.float64), size


def _bake(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, size: tuple[int, int], source,
          source_image: np.ndarray) -> np.ndarray:
    """The atlas (H, W, 3 uint8) of the charted copy: each texel takes the source's colour at the point of
    the source surface nearest to the texel's point; texels outside every chart take the nearest
    chart texel's colour (no dark seams under bilinear or mip-mapped lookups)."""
    from scipy import ndimage

    from recon._open3d import open3d
    from recon.imaging.pixels import sample_bilinear
    from recon.surface.raycast import scene_of
    from recon.surface.texture.raster import rasterize

    width, height = size
    corners = uv[faces] * [width, -height] + [0, height]  # texel coordinates, y down
    face_map, bary = rasterize(corners, np.arange(len(faces)), height, width)
    filled = face_map >= 0
    ids = face_map[filled]
    points = np.einsum("nk,nkd->nd", bary[filled].astype(np.float64), vertices[faces[ids]])
    centre = vertices.mean(axis=0)  # float32 queries near the scene, wherever it is
    src_vertices, src_faces = np.asarray(source.vertices) - centre, np.asarray(source.faces)
    o3d = open3d()
    nearest = scene_of(src_vertices, src_faces).compute_closest_points(
        o3d.core.Tensor(np.ascontiguousarray(points - centre, np.float32)))
    face = nearest["primitive_ids"].numpy().astype(np.int64)
    b = nearest["primitive_uvs"].numpy().astype(np.float64)
    weights = np.column_stack([1.0 - b.sum(axis=1), b])
    src_uv = np.einsum("nk,nkd->nd", weights, np.asarray(source.visual.uv, np.float64)[src_faces[face]])
    h, w = source_image.shape[:2]
    atlas = np.zeros((height, width, 3), source_image.dtype)
    # not cv2.remap: it refuses sources over 32767 px a side, which a large atlas can be
    atlas[filled] = np.round(sample_bilinear(source_image, src_uv[:, 0] * w, (1.0 - src_uv[:, 1]) * h))
    if filled.any() and not filled.all():
        near = ndimage.distance_transform_edt(~filled, return_distances=False, return_indices=True)
        atlas = atlas[near[0], near[1]]
    return atlas


def _jpeg(pixels: np.ndarray):
    """A PIL image that trimesh's glTF writer stores as JPEG (it keeps the format of a JPEG image)."""
    from PIL import Image

    image = Image.fromarray(pixels)
    image.format = "JPEG"
    return image
