"""texture: view selection, UV atlas, baking from the photos (as taken where their camera has no
distortion, else resampled into the undistorted view: :mod:`recon.surface.texture.sources`), seam
blending; exports textured.glb (embedded texture), textured.obj + .mtl + .png, and the vertex-coloured
mesh.ply."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.files import read_json
from recon.options import opt
from recon.products import DenseScene, PreparedPhotos, SparseModel, SurfaceMesh, TexturedModel
from recon.stage import Stage, StageContext, StageError, register
from recon.surface.options import TextureOptions


@dataclass(frozen=True)
class TextureConfig(TextureOptions):
    max_faces: int = opt(200000, "decimate the mesh to at most this many faces before texturing (0 = keep)", ge=0)


def write_exports(textured, out, georeference: dict | None = None) -> dict:
    """textured.glb, textured.obj/.mtl/.png (both recording the frame of ``georeference``, the
    content of georeference.json) and mesh.ply (levelled vertex colours); sizes in bytes."""
    from recon.surface.export import frame_record, write_glb, write_obj, write_ply

    frame = frame_record(georeference)
    paths = [write_glb(textured, out / "textured.glb", frame), write_obj(textured, out / "textured.obj", frame),
             write_ply(textured, out / "mesh.ply")]
    return {p.name: p.stat().st_size for p in paths}


@register
class Texture(Stage):
    name = "texture"
    version = 8
    Config = TextureConfig
    requires = (PreparedPhotos, SparseModel, DenseScene, SurfaceMesh)
    produces = TexturedModel
    summary = "texture atlas from the photos with seam blending: textured.glb, textured.obj"

    def run(self, ctx: StageContext, cfg: TextureConfig) -> dict:
        import trimesh

        from recon.surface.cleanup import decimate
        from recon.surface.texture import texture_mesh
        from recon.surface.texture.sources import texture_sources

        dense = ctx.input(DenseScene)
        mesh = trimesh.load(ctx.input(SurfaceMesh).path, process=False)
        if cfg.max_faces and len(mesh.faces) > cfg.max_faces:
            mesh = decimate(mesh, cfg.max_faces)
        views = dense.views()
        if not views:
            raise StageError("texture: the undistorted model has no registered photo")
        photos = ctx.input(PreparedPhotos)
        sources = texture_sources(views, dense.images, dense.masks, ctx.input(SparseModel).model(),
                                  photos.geometric, photos.masks)
        textured = texture_mesh(mesh, sources.images, sources.cameras, cfg, sources.masks)
        sizes = write_exports(textured, ctx.out, read_json(ctx.input(SparseModel).georeference))
        seen = float(np.mean(textured.face_view >= 0))
        return {"faces": len(textured.faces), "atlas": f"{textured.texture.shape[1]}x{textured.texture.shape[0]}",
                "faces_seen": round(seen, 3), "photos_as_taken": sources.as_taken,
                "photos_resampled": sources.resampled, "glb_mb": round(sizes["textured.glb"] / 1e6, 2)}
