"""Ground-truth cameras of evaluation datasets, read into one convention.

Every reader returns :class:`Camera` objects in COLMAP's convention (world-to-camera ``x = R X + t``,
pixel centres at half-integers, y down, z forward), keyed by image file name. Supported formats:

- Middlebury ``*_par.txt``: a count, then ``name k11..k33 r11..r33 t1 t2 t3`` with P = K [R | t].
  The file holds no image size: it is read from the images in ``images/`` beside ``gt/`` (or beside
  the file); when they cannot be found, width and height are 0 (unknown).
- Strecha ``<image>.camera`` files (fountain-P11 and friends): K (rows 1-3), distortion (row 4),
  camera-to-world R (rows 5-7), centre C (row 8), ``w h`` (row 9); so R_w2c = R^T, t = -R^T C.
- nerfstudio / instant-ngp ``transforms.json``: per-frame 4x4 camera-to-world matrices in OpenGL
  axes (x right, y up, z backwards); intrinsics ``fl_x fl_y cx cy w h`` (or ``camera_angle_x``)
  global or per frame. Distortion coefficients are ignored.
- recon synthetic scenes: ``gt/cameras.json`` with per-frame K, R, t, width, height, and ``radial``
  (k1, k2) where the lens has distortion.

Middlebury and Strecha intrinsics are taken as published; their principal points are not shifted by
half a pixel (their docs do not state the pixel-centre convention, and a 0.5 px shift of the
principal point is far below what the epipolar checks in the tests can resolve).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from recon.geometry.transforms import apply_matrix, camera_center, project

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".ppm", ".bmp")


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera: intrinsics ``K`` (3x3), world-to-camera ``R`` (3x3) and ``t`` (3,), image size
    in pixels (0 when the source does not say), and the lens's ``radial`` distortion (k1, k2) as in
    COLMAP's RADIAL model: a point at normalised radius r is imaged at r (1 + k1 r^2 + k2 r^4). A
    depth is camera z with or without distortion."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    radial: tuple[float, float] = (0.0, 0.0)

    @property
    def distorted(self) -> bool:
        return any(self.radial)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return camera_center(self.R, self.t)

    @property
    def P(self) -> np.ndarray:
        """The 3x4 projection matrix K [R | t]."""
        return self.K @ np.column_stack([self.R, self.t])

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths (N,) of world points (N, 3), through the lens's distortion."""
        if not self.distorted:
            return project(self.K, self.R, self.t, X)
        xy, z = project(np.eye(3), self.R, self.t, X)  # normalised image coordinates
        r2 = np.sum(xy * xy, axis=1, keepdims=True)
        k1, k2 = self.radial
        return apply_matrix(self.K[:2, :2], xy * (1 + k1 * r2 + k2 * r2 * r2)) + self.K[:2, 2], z

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Camera-frame directions with z = 1 (N, 3) of the rays imaged at pixels ``uv`` (N, 2): the
        lens's distortion undone by fixed-point iteration (to 1e-6 of a pixel within the frame of the
        lenses recon renders)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        distorted = apply_matrix(np.linalg.inv(self.K[:2, :2]), uv - self.K[:2, 2])
        xy = distorted.copy()
        if self.distorted:
            k1, k2 = self.radial
            for _ in range(50):
                r2 = np.sum(xy * xy, axis=1, keepdims=True)
                xy = distorted / (1 + k1 * r2 + k2 * r2 * r2)
        return np.column_stack([xy, np.ones(len(xy))])

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points (N, 3) imaged at pixels ``uv`` (N, 2) at camera depth ``depth`` (N,)."""
        xc = self.rays(uv) * np.asarray(depth, dtype=float).reshape(-1, 1)
        return apply_matrix(np.asarray(self.R, dtype=float).T, xc - np.asarray(self.t, dtype=float))

    def to_json(self, name: str) -> dict:
        out = {"name": name, "width": int(self.width), "height": int(self.height),
               "K": np.asarray(self.K).tolist(), "R": np.asarray(self.R).tolist(),
               "t": np.asarray(self.t).tolist()}
        return out | ({"radial": [float(k) for k in self.radial]} if self.distorted else {})


def _camera(K, R, t, width, height, radial=(0.0, 0.0)) -> Camera:
    return Camera(np.asarray(K, dtype=float).reshape(3, 3), np.asarray(R, dtype=float).reshape(3, 3),
                  np.asarray(t, dtype=float).reshape(3), int(width), int(height),
                  (float(radial[0]), float(radial[1])))


def load_cameras(path: str | Path) -> dict[str, Camera]:
    """Ground-truth cameras keyed by image file name, the format detected from ``path``.

    ``path`` may be a camera file (``*_par.txt``, ``transforms.json``, ``cameras.json``), a folder of
    Strecha ``*.camera`` files, or a dataset / synthetic-scene folder whose ``gt/`` holds one of them.
    """
    path = Path(path)
    if path.is_file():
        return _load_file(path)
    if not path.is_dir():
        raise FileNotFoundError(f"no ground truth at {path}")
    for folder in (path / "gt", path):
        if not folder.is_dir():
            continue
        found = _load_folder(folder)
        if found is not None:
            return found
    raise ValueError(f"no ground-truth camera format recognised in {path}")


def write_cameras(path: str | Path, cameras: dict[str, Camera]) -> None:
    """Write cameras as recon's ``cameras.json`` (``{"frames": [{name, width, height, K, R, t}, ...]}``)."""
    frames = [cam.to_json(name) for name, cam in cameras.items()]
    Path(path).write_text(json.dumps({"frames": frames}, indent=1))


def _load_file(path: Path) -> dict[str, Camera]:
    name = path.name
    if name.endswith("_par.txt"):
        return _read_middlebury(path)
    if name.endswith(".camera"):
        return {name[: -len(".camera")]: _read_strecha(path)}
    if path.suffix == ".json":
        data = json.loads(path.read_text())
        if "frames" in data and data["frames"] and "transform_matrix" in data["frames"][0]:
            return _read_transforms(data)
        if "frames" in data:
            return _read_recon(data)
    raise ValueError(f"unrecognised ground-truth camera file {path}")


def _load_folder(folder: Path) -> dict[str, Camera] | None:
    candidates = [folder / "cameras.json", folder / "transforms.json", *sorted(folder.glob("*_par.txt"))]
    for cand in candidates:
        if cand.is_file():
            return _load_file(cand)
    for sub in (folder, *sorted(p for p in folder.iterdir() if p.is_dir())):
        files = sorted(sub.glob("*.camera"))
        if files:
            return {f.name[: -len(".camera")]: _read_strecha(f) for f in files}
    return None


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image

    with Image.open(path) as im:
        return im.size


def _find_image(par_file: Path, name: str) -> Path | None:
    here = par_file.parent
    for folder in (here.parent / "images", here / "images", here, here.parent):
        if (folder / name).is_file():
            return folder / name
    return None


def _read_middlebury(path: Path) -> dict[str, Camera]:
    lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    count = int(lines[0][0])
    cams = {}
    for fields in lines[1 : 1 + count]:
        name, vals = fields[0], np.array(fields[1:22], dtype=float)
        image = _find_image(path, name)
        w, h = _image_size(image) if image is not None else (0, 0)
        cams[name] = _camera(vals[:9], vals[9:18], vals[18:21], w, h)
    if len(cams) != count:
        raise ValueError(f"{path}: header says {count} cameras, found {len(cams)}")
    return cams


def _read_strecha(path: Path) -> Camera:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    K = np.array(rows[0:3], dtype=float)
    R_c2w = np.array(rows[4:7], dtype=float)
    C = np.array(rows[7], dtype=float)
    w, h = (int(float(v)) for v in rows[8][:2])
    return _camera(K, R_c2w.T, -R_c2w.T @ C, w, h)


def _read_transforms(data: dict) -> dict[str, Camera]:
    cams = {}
    for frame in data["frames"]:
        def get(key, frame=frame):
            return frame.get(key, data.get(key))

        w, h = int(get("w")), int(get("h"))
        if get("fl_x") is not None:
            fx = float(get("fl_x"))
            fy = float(get("fl_y")) if get("fl_y") is not None else fx
        else:
            fx = 0.5 * w / math.tan(0.5 * float(get("camera_angle_x")))
            fy = 0.5 * h / math.tan(0.5 * float(get("camera_angle_y"))) if get("camera_angle_y") else fx
        cx = float(get("cx")) if get("cx") is not None else w / 2
        cy = float(get("cy")) if get("cy") is not None else h / 2
        c2w = np.asarray(frame["transform_matrix"], dtype=float)[:3, :4]
        R_c2w = c2w[:, :3] * np.array([1.0, -1.0, -1.0])  # OpenGL camera axes -> x right, y down, z forward
        R = R_c2w.T
        cams[Path(frame["file_path"]).name] = _camera([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], R,
                                                      -R @ c2w[:, 3], w, h)
    return cams


def _read_recon(data: dict) -> dict[str, Camera]:
    return {f["name"]: _camera(f["K"], f["R"], f["t"], f["width"], f["height"], f.get("radial", (0.0, 0.0)))
            for f in data["frames"]}
