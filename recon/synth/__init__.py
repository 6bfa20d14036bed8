"""Synthetic photogrammetry scenes with exact ground truth (cameras, depth, normals, surface).

A textured ground square with a few solids, textured with real photographs from scikit-image and
lit with view-independent Lambertian shading, ray cast from cameras on an orbit or a line:
:func:`render_scene` writes images and ground truth, :func:`load_scene` reads them back,
:func:`scene_cameras` gives the cameras alone. The zoo (:mod:`recon.synth.zoo`) holds named scenes
built from the same parts, each made to stress one thing that breaks dense reconstruction or
texturing, rendered by the same writer (:func:`recon.synth.dataset.write_scene`).
"""

from recon.synth.cameras import scene_cameras
from recon.synth.dataset import SceneInfo, load_scene, render_scene

__all__ = ["SceneInfo", "load_scene", "render_scene", "scene_cameras"]
