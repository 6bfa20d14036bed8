"""The geometry of a stereo pair: both cameras' intrinsics and the right camera's pose in the left's.

``R``, ``T`` map left-camera to right-camera coordinates, ``x_right = R @ x_left + T`` (OpenCV's
``stereoCalibrate`` output, COLMAP's relative pose). Intrinsics are :class:`Intrinsics` in COLMAP's
pixel convention; :func:`read_calibration` converts a file's OpenCV matrices.

Calibration file (YAML or JSON; an OpenCV ``FileStorage`` YAML/XML file with the same names works too)::

    image_size: [1280, 720]            # width, height of the photos the calibration was made with
    K1: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]   # left camera matrix, OpenCV pixel convention
    D1: [k1, k2, p1, p2]               # left distortion, OpenCV order (4, 5 or 8 values; optional)
    K2: [[...], [...], [...]]          # right camera matrix
    D2: [k1, k2, p1, p2, k3]           # right distortion (optional)
    R: [[...], [...], [...]]           # rotation left -> right camera
    T: [tx, ty, tz]                    # translation left -> right camera; its unit is the depth's unit
    image_size2: [1280, 720]           # optional: the right photos' size when it differs from the left's

OpenCV's pixel convention puts the top-left pixel's centre at (0, 0), as ``cv2.stereoCalibrate``
reports it; COLMAP's principal point is 0.5 px larger. Photos of another size with the same aspect
ratio get the intrinsics scaled to them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.geometry.transforms import compose_poses, invert_pose
from recon.imaging.intrinsics import Intrinsics


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Left and right intrinsics (COLMAP convention) and the pose of the right camera in the left's."""

    left: Intrinsics
    right: Intrinsics
    R: np.ndarray
    T: np.ndarray

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))

    def scaled(self, factor: float) -> StereoCalibration:
        """The pair for both photos resized by ``factor`` (sizes rounded to whole pixels)."""
        def size(cam: Intrinsics) -> tuple[int, int]:
            return max(1, round(cam.width * factor)), max(1, round(cam.height * factor))

        return StereoCalibration(self.left.scaled(*size(self.left)), self.right.scaled(*size(self.right)),
                                 self.R, self.T)

    def fitted(self, left_size: tuple[int, int], right_size: tuple[int, int]) -> StereoCalibration:
        """The pair for photos of these (width, height) sizes; a ValueError when a photo's aspect ratio
        differs from its calibration's by more than 1 %."""
        cams = []
        for cam, (w, h), side in ((self.left, left_size, "left"), (self.right, right_size, "right")):
            if abs((w / h) / (cam.width / cam.height) - 1) > 0.01:
                raise ValueError(f"the {side} photo is {w}x{h} but its calibration is for "
                                 f"{cam.width}x{cam.height} (another aspect ratio)")
            cams.append(cam if (w, h) == (cam.width, cam.height) else cam.scaled(w, h))
        return StereoCalibration(cams[0], cams[1], self.R, self.T)


def from_poses(left: Intrinsics, left_pose: tuple[np.ndarray, np.ndarray], right: Intrinsics,
               right_pose: tuple[np.ndarray, np.ndarray]) -> StereoCalibration:
    """The pair of two posed cameras (world-to-camera ``(R, t)`` each)."""
    R, T = compose_poses(right_pose, invert_pose(*left_pose))
    return StereoCalibration(left, right, R, T)


def read_calibration(path: str | Path) -> StereoCalibration:
    """A stereo calibration file (format: module doc). Raises ValueError naming what is wrong."""
    path = Path(path)
    data = _read_mapping(path)
    missing = [k for k in ("image_size", "K1", "K2", "R", "T") if k not in data]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)} (needs image_size, K1, D1, K2, D2, R, T)")
    try:
        width, height = (int(v) for v in np.ravel(data["image_size"]))
        width2, height2 = (int(v) for v in np.ravel(data.get("image_size2", (width, height))))
        K1, K2, R = (np.asarray(data[k], dtype=float).reshape(3, 3) for k in ("K1", "K2", "R"))
        T = np.asarray(data["T"], dtype=float).reshape(3)
        D1, D2 = (np.ravel(np.asarray(data.get(k, [0.0] * 4), dtype=float)) for k in ("D1", "D2"))
        left = Intrinsics.from_opencv(K1, D1, width, height)
        right = Intrinsics.from_opencv(K2, D2, width2, height2)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    if abs(np.linalg.det(R) - 1) > 1e-3 or not np.allclose(R @ R.T, np.eye(3), atol=1e-3):
        raise ValueError(f"{path}: R is not a rotation matrix")
    if not np.linalg.norm(T) > 0:
        raise ValueError(f"{path}: T is zero: the two cameras must be apart")
    return StereoCalibration(left, right, R, T)


def write_calibration(path: str | Path, calib: StereoCalibration) -> Path:
    """Write ``calib`` as a JSON calibration file that :func:`read_calibration` reads."""
    data = {"image_size": [calib.left.width, calib.left.height],
            "K1": calib.left.opencv_K().tolist(), "D1": calib.left.opencv_distortion().tolist(),
            "K2": calib.right.opencv_K().tolist(), "D2": calib.right.opencv_distortion().tolist(),
            "R": np.asarray(calib.R).tolist(), "T": np.asarray(calib.T).tolist()}
    if (calib.right.width, calib.right.height) != (calib.left.width, calib.left.height):
        data["image_size2"] = [calib.right.width, calib.right.height]
    path = Path(path)
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


def _read_mapping(path: Path) -> dict:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    if text.startswith("%YAML") or text.lstrip().startswith("<?xml"):
        return _read_opencv_storage(path)
    import yaml

    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot parse ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of image_size, K1, D1, K2, D2, R, T")
    return data


def _read_opencv_storage(path: Path) -> dict:
    """The named nodes of an OpenCV FileStorage file (matrices as arrays, sequences as lists)."""
    import cv2

    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        data = {}
        for key in ("image_size", "image_size2", "K1", "D1", "K2", "D2", "R", "T"):
            node = storage.getNode(key)
            if node.empty():
                continue
            if node.isSeq():
                data[key] = [node.at(i).real() for i in range(node.size())]
            else:
                data[key] = node.mat()
        return data
    finally:
        storage.release()
