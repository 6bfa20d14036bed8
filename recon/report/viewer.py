"""The 3D viewer's data: cameras as frustum line segments, sparse and dense points, the mesh, as
base64 typed arrays (float32 positions, uint8 colours, uint32 indices) that the page decodes; the
textured model as a GLB with the matrix placing it in the viewer's frame."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from recon.report.gather import Model
from recon.surface.export import Z_UP_TO_GLTF


def _b64(array: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def frustum_segments(model: Model, depth: float) -> np.ndarray:
    """Line segments (pairs of world points, 16 per camera): apex to the four image corners at
    ``depth`` in front of the camera, and the image rectangle."""
    segments = []
    for R, C, (fx, fy, cx, cy, w, h) in zip(model.rotations, model.centers, model.intrinsics):
        corners_cam = np.array([[(u - cx) / fx, (v - cy) / fy, 1.0] for u, v in ((0, 0), (w, 0), (w, h), (0, h))])
        corners = corners_cam * depth @ R + C  # x_world = R^T x_cam + C
        for k in range(4):
            segments += [C, corners[k], corners[k], corners[(k + 1) % 4]]
    return np.array(segments, dtype=float).reshape(-1, 3)


def payload(model: Model | None, dense: tuple[np.ndarray, np.ndarray] | None,
            mesh: Path | None, max_mesh_faces: int, glb: bytes | None, max_points: int) -> dict:
    """Everything the viewer draws, in coordinates relative to ``origin`` (float32 keeps its precision
    near the scene even when the model is geo-referenced far from zero); at most ``max_points`` sparse
    points (a random subset beyond). ``glb`` is in glTF's Y-up frame, as the texture stage writes it."""
    clouds = [a for a in (model.points if model is not None else None, dense[0] if dense else None)
              if a is not None and len(a)]
    anchor = np.vstack(clouds) if clouds else (model.centers if model is not None and len(model.centers)
                                               else np.zeros((1, 3)))
    origin = np.median(anchor, axis=0)
    lo, hi = np.percentile(anchor, [5, 95], axis=0)
    radius = float(np.linalg.norm(hi - lo) / 2)
    if model is not None and len(model.centers):  # frame the cameras too (a ring around a small object)
        radius = max(radius, float(np.median(np.linalg.norm(model.centers - origin, axis=1))))
    radius = max(radius, 1e-6)
    data: dict = {"origin": origin.tolist(), "radius": radius,
                  "up": (model.up if model is not None else np.array([0.0, 0.0, 1.0])).tolist(), "layers": []}
    if model is not None and len(model.names):
        segments = frustum_segments(model, 0.06 * radius) - origin
        data["layers"].append({"id": "cameras", "label": f"cameras ({len(model.names)})", "kind": "lines",
                               "positions": _b64(segments, np.float32), "color": "#e8553e"})
        if len(model.points):
            keep = np.arange(len(model.points))
            if len(keep) > max_points:
                keep = np.sort(np.random.default_rng(0).choice(len(keep), max_points, replace=False))
            shown = "" if len(keep) == len(model.points) else f"{len(keep)} of "
            data["layers"].append({"id": "sparse-points", "label": f"sparse points ({shown}{len(model.points)})",
                                   "kind": "points", "positions": _b64(model.points[keep] - origin, np.float32),
                                   "colors": _b64(model.colors[keep], np.uint8), "size": 3})
    if dense is not None and len(dense[0]):
        data["layers"].append({"id": "dense", "label": f"dense points ({len(dense[0])} shown)", "kind": "points",
                               "positions": _b64(dense[0] - origin, np.float32),
                               "colors": _b64(dense[1], np.uint8), "size": 1.5, "visible": True})
    if glb is not None:
        data["layers"].append({"id": "textured", "label": "textured mesh", "kind": "glb",
                               "data": base64.b64encode(glb).decode("ascii"),
                               "matrix": glb_to_viewer(origin).T.ravel().tolist()})  # three.js: column-major
    elif mesh is not None:
        layer = mesh_layer(mesh, max_mesh_faces, origin)
        if layer is not None:
            data["layers"].append(layer)
    return data


def glb_to_viewer(origin: np.ndarray) -> np.ndarray:
    """4 x 4 matrix from glTF's Y-up frame back to recon's Z-up world, less ``origin``."""
    shift = np.eye(4)
    shift[:3, 3] = -np.asarray(origin, float)
    return shift @ np.linalg.inv(Z_UP_TO_GLTF)


def mesh_layer(path: Path, max_faces: int, origin: np.ndarray) -> dict | None:
    """mesh.ply as indexed triangles with vertex colours, or None when it has more than ``max_faces``."""
    import trimesh

    mesh = trimesh.load(path, process=False, force="mesh")
    if len(mesh.faces) == 0 or len(mesh.faces) > max_faces:
        return None
    layer = {"id": "mesh", "label": f"mesh ({len(mesh.faces)} faces)", "kind": "mesh",
             "positions": _b64(np.asarray(mesh.vertices) - origin, np.float32),
             "indices": _b64(mesh.faces, np.uint32)}
    if mesh.visual.kind == "vertex":
        layer["colors"] = _b64(np.asarray(mesh.visual.vertex_colors)[:, :3], np.uint8)
    return layer
