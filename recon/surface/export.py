"""Writing surfaces: textured glTF binary (GLB, texture embedded), Wavefront OBJ + MTL + PNG, and PLY with
vertex colours."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj

from recon.surface.texture.model import TexturedMesh

log = logging.getLogger(__name__)


#: recon's frame has its up along +Z (recon/sparse/frame.py); glTF's is +Y: (x, y, z) -> (x, z, -y)
Z_UP_TO_GLTF = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def frame_record(georeference: dict | None) -> dict | None:
    """What a mesh file records of its frame: the CRS, the WGS84 origin and the UTM offset from
    georeference.json (None when the model is not placed on the Earth)."""
    if not georeference or not georeference.get("georeferenced") or not georeference.get("origin"):
        return None
    record = {"crs": georeference["crs"], "origin_wgs84": georeference["origin"]}
    utm = georeference.get("utm") or {}
    if utm.get("used"):
        record["utm_offset"] = utm["offset"]
    return record


def write_glb(textured: TexturedMesh, path: str | Path, frame: dict | None = None) -> Path:
    """A GLB holding the mesh, its UVs and the atlas (PNG) as the base colour texture, in glTF's
    Y-up frame; the material is double-sided where the surface is open (a viewer would otherwise
    cull the back of every face seen from outside the captured side). ``frame``
    (:func:`frame_record`) goes into the asset's ``extras.georeference``, with the axes."""
    path = Path(path)
    mesh = textured.to_trimesh()
    mesh.apply_transform(Z_UP_TO_GLTF)
    mesh.visual.material.doubleSided = not mesh.is_watertight

    def record_frame(tree: dict) -> None:
        if frame is not None:
            axes = "glTF Y up: glTF (x, y, z) = frame (x, z, -y)"
            tree["asset"].setdefault("extras", {})["georeference"] = {**frame, "axes": axes}

    path.write_bytes(mesh.export(file_type="glb", tree_postprocessor=record_frame))
    log.info("wrote %s (%d faces, %d x %d texture)", path, len(textured.faces), textured.texture.shape[1],
             textured.texture.shape[0])
    return path


def read_glb(path: str | Path) -> trimesh.Trimesh:
    """A GLB written by :func:`write_glb` as a mesh in recon's frame (Z up), texture included."""
    mesh = trimesh.load(path, force="mesh")
    mesh.apply_transform(np.linalg.inv(Z_UP_TO_GLTF))
    return mesh


def write_obj(textured: TexturedMesh, path: str | Path, frame: dict | None = None) -> Path:
    """``<name>.obj`` with ``<name>.mtl`` and the atlas as ``<name>.png`` beside it, ``frame``
    (:func:`frame_record`) as a comment line ``# georeference: {json}`` at the top; returns the OBJ's path."""
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
    if frame is not None:
        text = f"# georeference: {json.dumps(frame)}\n{text}"
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
