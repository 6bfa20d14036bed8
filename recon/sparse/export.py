"""Sparse model exports that other tools read: a coloured PLY and nerfstudio's transforms.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# nerfstudio's OPENCV camera has k1, k2, p1, p2; COLMAP's parameter order per model
_DISTORTION = {
    "SIMPLE_PINHOLE": {}, "PINHOLE": {},
    "SIMPLE_RADIAL": {"k1": 3},
    "RADIAL": {"k1": 3, "k2": 4},
    "OPENCV": {"k1": 4, "k2": 5, "p1": 6, "p2": 7},
}


def write_points_ply(rec, path: Path) -> int:
    """Sparse points with colours as a binary PLY (MeshLab, CloudCompare, trimesh read it)."""
    import trimesh

    pts = rec.points3D
    xyz = np.array([p.xyz for p in pts.values()], np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts.values()], np.uint8).reshape(-1, 3)
    cloud = trimesh.PointCloud(xyz, colors=np.c_[rgb, np.full(len(rgb), 255, np.uint8)])
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(cloud.export(file_type="ply"))
    tmp.replace(path)
    return len(xyz)


def intrinsics(camera) -> dict:
    """nerfstudio intrinsics of a COLMAP camera (pinhole models become OPENCV with zero distortion)."""
    model = camera.model.name
    if model not in _DISTORTION:
        raise ValueError(f"camera model {model} has no nerfstudio equivalent here")
    p = list(camera.params)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
    else:
        fx, fy, cx, cy = p[:4]
    out = {"camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
           "w": camera.width, "h": camera.height, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
    out.update({k: p[i] for k, i in _DISTORTION[model].items()})
    return out


def opengl_camera_to_world(cam_from_world: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world in nerfstudio's axes (OpenGL camera: x right, y up, z back)."""
    w2c = np.eye(4)
    w2c[:3, :4] = cam_from_world
    c2w = np.linalg.inv(w2c)
    c2w[:3, 1:3] *= -1  # COLMAP/OpenCV camera (y down, z forward) -> OpenGL camera
    return c2w


def transforms_json(rec, image_prefix: str = "images/") -> dict:
    """nerfstudio's transforms.json for a COLMAP model (the layout ns-process-data writes).

    World axes are COLMAP's (``applied_transform`` is the identity); intrinsics are global when the
    model has one camera, per frame otherwise.
    """
    cameras = {cid: intrinsics(cam) for cid, cam in rec.cameras.items()}
    single = len(cameras) == 1
    data: dict = dict(next(iter(cameras.values()))) if single else {}
    frames = []
    for image_id in sorted(rec.reg_image_ids(), key=lambda i: rec.image(i).name):
        image = rec.image(image_id)
        frame = {"file_path": image_prefix + image.name,
                 "transform_matrix": opengl_camera_to_world(image.cam_from_world().matrix()).tolist(),
                 "colmap_im_id": image_id}
        if not single:
            frame.update(cameras[image.camera_id])
        frames.append(frame)
    data["frames"] = frames
    data["applied_transform"] = np.eye(4)[:3].tolist()
    return data
