"""Writing surfaces: textured glTF binary (GLB, texture embedded), Wavefront OBJ + MTL + PNG, and PLY with
vertex colours."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj

from recon.surface.texture.model import TexturedMesh

log = logging.getLogger(__name__)


#: recon's frame has its up along +Z (recon/sparse/frame.py); glTF's is +Y: (x, y, z) -> (x, z, -y)
Z_UP_TO_GLTF = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def write_glb(textured: TexturedMesh, path: str | Path) -> Path:
    """A GLB holding the mesh, its UVs and the atlas (PNG) as the base colour texture, in glTF's
    Y-up frame; the material is double-sided where the surface is open (a viewer would otherwise
    cull the back of every face seen from outside the captured side)."""
    path = Path(path)
    mesh = textured.to_trimesh()
    mesh.apply_transform(Z_UP_TO_GLTF)
    mesh.visual.material.doubleSided = not mesh.is_watertight
    path.write_bytes(mesh.export(file_type="glb"))
    log.info("wrote %s (%d faces, %d x %d texture)", path, len(textured.faces), textured.texture.shape[1],
             textured.texture.shape[0])
    return path


def read_glb(path: str | Path) -> trimesh.Trimesh:
    """A GLB written by :func:`write_glb` as a mesh in recon's frame (Z up), texture included."""
    mesh = trimesh.load(path, force="mesh")
    mesh.apply_transform(np.linalg.inv(Z_UP_TO_GLTF))
    return mesh


def write_obj(textured: TexturedMesh, path: str | Path) -> Path:
    """``<name>.obj`` with ``<name>.mtl`` and the atlas as ``<name>.png`` beside it; returns the OBJ's path."""
    path = Path(path)
    mesh = textured.to_trimesh()
    # white diffuse and ambient, no specular: viewers multiply map_Kd by Kd (trimesh's default is 0.4 grey)
    mesh.visual.material = trimesh.visual.material.SimpleMaterial(
        image=mesh.visual.material.baseColorTexture, diffuse=(255, 255, 255, 255), ambient=(255, 255, 255, 255),
        specular=(0, 0, 0, 255), name=path.stem)
    text, files = export_obj(mesh, include_normals=False, include_texture=True, return_texture=True,
                             mtl_name=f"{path.stem}.mtl")
    for name, data in files.items():
        (path.parent / name).write_bytes(data)
    path.write_text(text)
    log.info("wrote %s with %s", path, ", ".join(sorted(files)))
    return path


def write_ply(mesh: trimesh.Trimesh | TexturedMesh, path: str | Path) -> Path:
    """A binary PLY of the mesh with its vertex colours (a TexturedMesh gives its levelled vertex colours)."""
    path = Path(path)
    if isinstance(mesh, TexturedMesh):
        mesh = mesh.colored_mesh()
    path.write_bytes(mesh.export(file_type="ply"))
    return path
