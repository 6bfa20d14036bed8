"""The textured mesh that texture mapping produces and the exporters write."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from PIL import Image

from recon.surface.indexing import unique_rows


@dataclass(frozen=True)
class TexturedMesh:
    """A triangle mesh with one texture atlas.

    ``uv`` holds each face corner's texture coordinate (F, 3, 2) in OBJ/trimesh convention: u to the right,
    v up, (0, 0) the atlas' bottom-left corner. ``face_view`` is the photo each face was textured from
    (-1: seen by none, filled from its neighbours); ``vertex_colors`` are the levelled colours (uint8).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    face_view: np.ndarray
    vertex_colors: np.ndarray

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh with per-vertex UVs: vertices are split where faces give them different UVs."""
        corner_v = self.faces.reshape(-1)
        corner_uv = self.uv.reshape(-1, 2)
        key = np.concatenate([corner_v[:, None], np.round(np.clip(corner_uv, 0, 1) * 2**20).astype(np.int64)], axis=1)
        _, first, inverse = unique_rows(key, return_index=True, return_inverse=True)
        material = trimesh.visual.material.PBRMaterial(
            baseColorTexture=Image.fromarray(self.texture), metallicFactor=0.0, roughnessFactor=1.0)
        visual = trimesh.visual.TextureVisuals(uv=corner_uv[first], material=material)
        return trimesh.Trimesh(self.vertices[corner_v[first]], inverse.reshape(-1, 3), visual=visual,
                               process=False)

    def colored_mesh(self) -> trimesh.Trimesh:
        """The same surface with only its vertex colours."""
        return trimesh.Trimesh(self.vertices, self.faces, vertex_colors=self.vertex_colors, process=False)
