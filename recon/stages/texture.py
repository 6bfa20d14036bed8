"""texture: view selection, UV atlas, baking from the undistorted photos, seam blending; exports
textured.glb (embedded texture), textured.obj + .mtl + .png, and the vertex-coloured mesh.ply."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.files import read_json
from recon.options import opt
from recon.products import DenseScene, SparseModel, SurfaceMesh, TexturedModel
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
    version = 6
    Config = TextureConfig
    requires = (SparseModel, DenseScene, SurfaceMesh)
    produces = TexturedModel
    summary = "texture atlas from the photos with seam blending: textured.glb, textured.obj"

    def run(self, ctx: StageContext, cfg: TextureConfig) -> dict:
        import cv2
        import trimesh

        from recon.surface.cleanup import decimate
        from recon.surface.texture import texture_mesh

        dense = ctx.input(DenseScene)
        mesh = trimesh.load(ctx.input(SurfaceMesh).path, process=False)
        if cfg.max_faces and len(mesh.faces) > cfg.max_faces:
            mesh = decimate(mesh, cfg.max_faces)
        views = dense.views()
        if not views:
            raise StageError("texture: the undistorted model has no registered photo")
        images = [cv2.cvtColor(cv2.imread(str(dense.images / v.name)), cv2.COLOR_BGR2RGB) for v in views]
        masks = [dense.mask(v.name) for v in views] if dense.masks.is_dir() else None
        textured = texture_mesh(mesh, images, views, cfg, masks)
        sizes = write_exports(textured, ctx.out, read_json(ctx.input(SparseModel).georeference))
        seen = float(np.mean(textured.face_view >= 0))
        return {"faces": len(textured.faces), "atlas": f"{textured.texture.shape[1]}x{textured.texture.shape[0]}",
                "faces_seen": round(seen, 3), "glb_mb": round(sizes["textured.glb"] / 1e6, 2)}
