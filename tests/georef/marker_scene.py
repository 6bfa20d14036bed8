"""Test helper: the seeded synthetic scene with printed targets, and their true corners. In place of its
second box and its sphere: an ArUco marker (DICT_4X4_50, id 7) on the ground, another (id 3) on top
of the remaining box, and a chessboard of 4 x 3 inner corners on the ground; each printed with a
white margin (two modules around a marker, a square around the board). The scene's unit is read as
the metre."""

from __future__ import annotations

import cv2
import numpy as np

from recon.synth import SceneInfo
from recon.synth.cameras import scene_cameras
from recon.synth.dataset import write_scene
from recon.synth.scene import assemble, build_scene
from recon.synth.shapes import quad
from recon.synth.textures import make_texture

MARKER_SIDE = 0.39  # the black square's side
SHEET = MARKER_SIDE / 0.6  # the printed sheet: 6 modules of marker and 2 of margin each side
SQUARE = 0.15
INNER = (4, 3)  # columns, rows of inner corners
_LIFT = 0.002  # the prints lie this far above the surface under them


def _sheets() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each print's (p0, e1, e2) as :func:`recon.synth.shapes.quad` takes them (e1 along the image's
    columns, e2 up its rows)."""
    parts = {p.name: p for p in build_scene(0).parts}
    top = parts["box_a_4"].vertices  # the top face: p0, p0 + e1, p0 + e1 + e2, p0 + e2
    e1, e2 = top[1] - top[0], top[3] - top[0]
    e1, e2 = SHEET * e1 / np.linalg.norm(e1), SHEET * e2 / np.linalg.norm(e2)
    on_box = top.mean(axis=0) + [0, 0, _LIFT] - (e1 + e2) / 2
    cols, rows = INNER
    width, height = (cols + 3) * SQUARE, (rows + 3) * SQUARE
    return {
        "marker_7": (np.array([0.8 - SHEET / 2, 0.25 - SHEET / 2, _LIFT]), np.array([SHEET, 0, 0]),
                     np.array([0, SHEET, 0])),
        "marker_3": (on_box, e1, e2),
        "board": (np.array([-0.45 - width / 2, -0.3 - height / 2, _LIFT]), np.array([width, 0, 0]),
                  np.array([0, height, 0])),
    }


def marker_corners() -> dict[int, np.ndarray]:
    """Marker id -> its four corners (4, 3) in OpenCV's order (the printed image's top-left, top-right,
    bottom-right, bottom-left)."""
    out = {}
    for marker, (p0, e1, e2) in ((7, _sheets()["marker_7"]), (3, _sheets()["marker_3"])):
        out[marker] = np.array([p0 + a * e1 + b * e2 for a, b in ((0.2, 0.8), (0.8, 0.8), (0.8, 0.2), (0.2, 0.2))])
    return out


def board_corners() -> np.ndarray:
    """The board's inner corners (columns x rows, 3), row by row from the printed image's top-left."""
    p0, e1, e2 = _sheets()["board"]
    cols, rows = INNER
    return np.array([p0 + (2 + c) / (cols + 3) * e1 + (1 - (2 + r) / (rows + 3)) * e2
                     for r in range(rows) for c in range(cols)])


def render_marker_scene(out, width: int = 320, height: int = 240) -> SceneInfo:
    """16 orbit views of the scene (the cameras of ``render_scene(views=16, seed=0)``)."""
    kept = [p for p in build_scene(0).parts if not p.name.startswith(("box_b", "sphere"))]
    sheets = _sheets()
    prints = [quad(name, *sheets[name], make_texture(image)) for name, image in
              (("marker_7", _marker_image(7)), ("marker_3", _marker_image(3)), ("board", _board_image()))]
    regular, _ = scene_cameras(16, width, height, 0)
    return write_scene(out, assemble([*kept, *prints]), regular, {}, seed=0, path="orbit")


def _marker_image(marker: int, texels: int = 320) -> np.ndarray:
    inner = texels * 6 // 10
    image = np.full((texels, texels), 255, np.uint8)
    margin = (texels - inner) // 2
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    image[margin:margin + inner, margin:margin + inner] = cv2.aruco.generateImageMarker(dictionary, marker, inner)
    return np.repeat(image[:, :, None], 3, axis=2)


def _board_image(texels: int = 32) -> np.ndarray:
    cols, rows = INNER
    image = np.full(((rows + 3) * texels, (cols + 3) * texels), 255, np.uint8)
    for r in range(rows + 1):
        for c in range(cols + 1):
            if (r + c) % 2 == 0:
                image[(1 + r) * texels:(2 + r) * texels, (1 + c) * texels:(2 + c) * texels] = 0
    return np.repeat(image[:, :, None], 3, axis=2)
