"""Sparse model exports that other tools read: a coloured PLY and nerfstudio's transforms.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.files import write_bytes

# nerfstudio's camera model and its distortion fields (index into COLMAP's parameters) per COLMAP model:
# OPENCV has k1, k2, p1, p2; OPENCV_FISHEYE k1..k4 (theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8),
# which COLMAP's fisheye models are with fewer terms)
_NERFSTUDIO = {
    "SIMPLE_PINHOLE": ("OPENCV", {}), "PINHOLE": ("OPENCV", {}),
    "SIMPLE_RADIAL": ("OPENCV", {"k1": 3}),
    "RADIAL": ("OPENCV", {"k1": 3, "k2": 4}),
    "OPENCV": ("OPENCV", {"k1": 4, "k2": 5, "p1": 6, "p2": 7}),
    "SIMPLE_FISHEYE": ("OPENCV_FISHEYE", {}), "FISHEYE": ("OPENCV_FISHEYE", {}),
    "SIMPLE_RADIAL_FISHEYE": ("OPENCV_FISHEYE", {"k1": 3}),
    "RADIAL_FISHEYE": ("OPENCV_FISHEYE", {"k1": 3, "k2": 4}),
    "OPENCV_FISHEYE": ("OPENCV_FISHEYE", {"k1": 4, "k2": 5, "k3": 6, "k4": 7}),
}
_ZERO_DISTORTION = {"OPENCV": ("k1", "k2", "p1", "p2"), "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4")}


def write_points_ply(rec, path: Path) -> int:
    """Sparse points with colours as a binary PLY (MeshLab, CloudCompare, trimesh read it)."""
    import trimesh

    pts = rec.points3D
    xyz = np.array([p.xyz for p in pts.values()], np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts.values()], np.uint8).reshape(-1, 3)
    cloud = trimesh.PointCloud(xyz, colors=np.c_[rgb, np.full(len(rgb), 255, np.uint8)])
    write_bytes(path, cloud.export(file_type="ply"))
    return len(xyz)


def intrinsics(camera) -> dict:
    """nerfstudio intrinsics of a COLMAP camera: pinhole models become OPENCV, fisheye models
    OPENCV_FISHEYE; an equirectangular camera is EQUIRECTANGULAR with fl_x = fl_y = w / 2 and the
    principal point at the centre, as nerfstudio's ray generation expects (its centre column looks
    forward, as COLMAP's does)."""
    model = camera.model.name
    w, h = camera.width, camera.height
    if model == "EQUIRECTANGULAR":
        return {"camera_model": "EQUIRECTANGULAR", "fl_x": w / 2, "fl_y": w / 2, "cx": w / 2, "cy": h / 2,
                "w": w, "h": h}
    if model not in _NERFSTUDIO:
        raise ValueError(f"camera model {model} has no nerfstudio equivalent here")
    kind, distortion = _NERFSTUDIO[model]
    p = list(camera.params)
    out = {"camera_model": kind, "fl_x": camera.focal_length_x, "fl_y": camera.focal_length_y,
           "cx": camera.principal_point_x, "cy": camera.principal_point_y, "w": w, "h": h,
           **dict.fromkeys(_ZERO_DISTORTION[kind], 0.0)}
    out.update({k: p[i] for k, i in distortion.items()})
    return out


def opengl_camera_to_world(cam_from_world: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world in nerfstudio's axes (OpenGL camera: x right, y up, z back)."""
    w2c = np.eye(4)
    w2c[:3, :4] = cam_from_world
    c2w = np.linalg.inv(w2c)
    c2w[:3, 1:3] *= -1  # COLMAP/OpenCV camera (y down, z forward) -> OpenGL camera
    return c2w


def transforms_json(rec, image_prefix: str = "images/", points_file: str | None = None) -> dict:
    """nerfstudio's transforms.json for a COLMAP model (the layout ns-process-data writes).

    World axes are COLMAP's (``applied_transform`` is the identity); intrinsics are global when the
    model has one camera, per frame otherwise. ``points_file``, the sparse points' PLY relative to
    transforms.json, becomes ``ply_file_path``: nerfstudio's dataparser loads it (open3d) as the
    initial points of splatfacto.
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
    if points_file is not None:
        data["ply_file_path"] = points_file
    return data
