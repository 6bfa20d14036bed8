"""Mesh faces the photos show as sky or backdrop are dropped: a surface run on past its edge.

The mvs stage clears the depths its matching window carried from a surface's edge onto the sky beside it
(:mod:`recon.mvs.background`), but only where a pixel shares the sky's shade. The pixels right at the
edge blend both shades and keep the surface's depth. Seen at a grazing angle, as a horizon always is, that
pixel or two is a long strip of surface, and the views that share it fuse it into a fringe past the true
edge. On the zoo's noisy_phone, a ground square against a light sky, 4 % of the mesh's area lay beyond
the ground's edge: 86 % of the mesh's area that missed the truth by more than 0.2 % of the scene.

So a face goes where more views show the photo's background at its centre than hold a depth that agrees
with it (within :data:`recon.mvs.free_space.AGREE`). A view shows the background at a face when it sees
the face (in front of its first hit on the mesh) on a pixel of :func:`backdrop_rim`, and no mesh lies
behind the face along its line of sight. Each part of the test keeps true surface that a looser one
dropped, measured on the zoo's final meshes of session 37 (docs/DECISIONS.md):

- The count: where a uniform face of an object runs out of a photo unmeasured, that photo calls it
  background (clutter: a grey cylinder's side, 2.6 % of a photo), while the views that measured the face
  agree with it. Dropping every face some view shows over its background took 8,419 of clutter's 200,000
  faces, 81 % of them within 0.2 % of the scene of the truth (mesh F@0.2 % .951 -> .945).
- Nothing behind: dropping the face must show what the photo shows there, nothing. A closed object's face
  against a black backdrop whose shade it shares has the object's far side behind it (turntable_black:
  232 faces dropped without this test, 103 with it; held-out texture 29.44 -> 29.23 and 29.33 dB).
- The rim: only the background within the matching window's radius of its edge counts, where a
  surface's edge carried on by the window lands. Deeper in, an unmeasured face's inside is not what a
  fringe covers: with the whole background, clutter lost 1,296 faces and 2,879 of the held-out views'
  surface pixels, with the rim 631 faces and 656 pixels. noisy_phone loses the same 4,034 faces either
  way, 0.3 % of them on the truth: mesh F@0.2 % .969 -> .978.
"""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np
import trimesh

from recon.mvs.background import background_reach
from recon.mvs.free_space import AGREE, agreeing_points
from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import untextured
from recon.mvs.views import ViewCamera
from recon.surface.masking import seen_on
from recon.surface.raycast import scene_of
from recon.surface.seen_through import mesh_behind


def backdrop_rim(image: np.ndarray, depth: np.ndarray, options: MVSOptions) -> np.ndarray:
    """Bool mask of the pixels of a photo's background (:func:`recon.mvs.background.background_reach` of the
    grey ``image`` in [0, 1] and its final ``depth`` map, same size) within ``options.window_radius`` px of
    its edge: where a surface's edge carried on by the matching window lands (module doc)."""
    reach = background_reach(image, untextured(image, options), depth, options)
    if not reach.any():
        return reach
    inside = cv2.distanceTransform(reach.astype(np.uint8), cv2.DIST_L2, 5)
    return reach & (inside <= options.window_radius)


def backdrop_faces(mesh: trimesh.Trimesh, views: Iterable[tuple[ViewCamera, np.ndarray, np.ndarray]]) -> np.ndarray:
    """Boolean per face of ``mesh``: more of ``views`` (camera, its depth map, its :func:`backdrop_rim` at any
    resolution) show the background at the face's centre than agree with the centre's depth (module doc)."""
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    if len(faces) == 0:
        return np.zeros(0, bool)
    scene = scene_of(vertices, faces)
    centres = vertices[faces].mean(axis=1)
    showing = np.zeros(len(faces), np.int32)
    agreeing = np.zeros(len(faces), np.int32)
    for view, depth, rim in views:
        if rim.any():
            shown = seen_on(scene, centres, view, rim)
            showing[shown[~mesh_behind(scene, centres[shown], view)]] += 1
        agreeing += agreeing_points(centres, view, depth, AGREE)
    return showing > agreeing
