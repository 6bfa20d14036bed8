"""texture: view selection, UV atlas, baking from the undistorted photos, seam levelling; exports
textured.glb (embedded texture), textured.obj + .mtl + .png, and the vertex-coloured mesh.ply."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.options import opt
from recon.stage import Stage, StageContext, StageError, register
from recon.surface.options import TextureOptions


@dataclass(frozen=True)
class TextureConfig(TextureOptions):
    max_faces: int = opt(200000, "decimate the mesh to at most this many faces before texturing (0 = keep)", ge=0)


def write_exports(textured, out) -> dict:
    """textured.glb, textured.obj/.mtl/.png and mesh.ply (levelled vertex colours), each written atomically."""
    from trimesh.exchange.obj import export_obj

    tm = textured.to_trimesh()
    files = {"textured.glb": tm.export(file_type="glb")}
    obj_text, extra = export_obj(tm, include_texture=True, return_texture=True, mtl_name="textured.mtl")
    files["textured.obj"] = obj_text.encode()
    images = [name for name in extra if name != "textured.mtl"]
    mtl = extra["textured.mtl"].decode()
    for name in images:  # one atlas: name it after the model
        mtl = mtl.replace(name, "textured.png")
        files["textured.png"] = extra[name]
    files["textured.mtl"] = mtl.encode()
    files["mesh.ply"] = textured.colored_mesh().export(file_type="ply")
    for name, data in files.items():
        tmp = out / f".{name}.tmp"
        tmp.write_bytes(data if isinstance(data, bytes) else bytes(data))
        tmp.replace(out / name)
    return {name: len(data) for name, data in files.items()}


@register
class Texture(Stage):
    name = "texture"
    version = 1
    Config = TextureConfig
    requires = ("undistort", "mesh")
    outputs = ("textured.glb", "textured.obj", "textured.mtl", "textured.png", "mesh.ply")
    publish = {"textured.glb": "textured.glb", "textured.obj": "textured.obj", "textured.mtl": "textured.mtl",
               "textured.png": "textured.png", "mesh.ply": "mesh.ply"}
    summary = "texture atlas from the photos with seam levelling: textured.glb, textured.obj"

    def run(self, ctx: StageContext, cfg: TextureConfig) -> dict:
        import cv2
        import trimesh

        from recon.stages.mesh import dense_views
        from recon.surface.cleanup import decimate
        from recon.surface.texture import texture_mesh

        dense = ctx.input("undistort") / "dense"
        mesh = trimesh.load(ctx.input("mesh") / "mesh.ply", process=False)
        if cfg.max_faces and len(mesh.faces) > cfg.max_faces:
            mesh = decimate(mesh, cfg.max_faces)
        views = dense_views(dense)
        if not views:
            raise StageError("texture: the undistorted model has no registered photo")
        images = [cv2.cvtColor(cv2.imread(str(dense / "images" / v.name)), cv2.COLOR_BGR2RGB) for v in views]
        textured = texture_mesh(mesh, images, views, cfg)
        sizes = write_exports(textured, ctx.out)
        seen = float(np.mean(textured.face_view >= 0))
        return {"faces": len(textured.faces), "atlas": f"{textured.texture.shape[1]}x{textured.texture.shape[0]}",
                "faces_seen": round(seen, 3), "glb_mb": round(sizes["textured.glb"] / 1e6, 2)}
