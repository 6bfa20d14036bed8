"""Camera calibration from views of a planar target, and a renderer of such views for tests.

Targets: a chessboard (cv2.findChessboardCorners + cornerSubPix) or a ChArUco board
(cv2.aruco.CharucoDetector; partial views are fine since every corner carries its id). Both feed
cv2.calibrateCamera with flags that restrict it to the COLMAP model asked for, and the result is
an :class:`Intrinsics` in COLMAP's pixel convention plus the RMS reprojection error.

The renderer (:func:`render_board_views`) images a board texture lying on the world plane Z = 0
through a camera with known intrinsics and distortion. For every output sub-pixel sample it takes
the undistorted ray (the distortion inverted by Newton's method at pixel corners, once per camera,
and interpolated inside pixels), maps it through the plane's homography to the texture, samples
the texture bilinearly and box-averages the samples into the pixel (anti-aliasing).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from recon.imaging.intrinsics import Intrinsics
from recon.imaging.pixels import check_image, max_value, to_gray
from recon.options import opt

logger = logging.getLogger(__name__)

CalibrationModel = Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"]

_NO_DISTORTION = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
# cv2.calibrateCamera flags that make it estimate exactly the parameters of each COLMAP model.
_MODEL_FLAGS = {
    "SIMPLE_PINHOLE": cv2.CALIB_FIX_ASPECT_RATIO | _NO_DISTORTION,
    "PINHOLE": _NO_DISTORTION,
    "SIMPLE_RADIAL": cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2
    | cv2.CALIB_FIX_K3,
    "RADIAL": cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    "OPENCV": cv2.CALIB_FIX_K3,
    "FULL_OPENCV": cv2.CALIB_RATIONAL_MODEL,
}


@dataclass(frozen=True)
class Chessboard:
    """A chessboard target; ``columns`` x ``rows`` counts inner corners (squares: one more each way)."""

    columns: int = opt(9, "inner corners along a row of the board", ge=2)
    rows: int = opt(6, "inner corners along a column of the board", ge=2)
    square_size: float = opt(1.0, "side of one square in world units (sets the unit of the poses)", gt=0.0)

    def object_points(self) -> np.ndarray:
        """(rows*columns, 3) inner-corner positions on Z = 0, in cv2.findChessboardCorners order."""
        j, i = np.mgrid[0:self.rows, 0:self.columns]
        return np.stack([(i + 1) * self.square_size, (j + 1) * self.square_size,
                         np.zeros_like(i, float)], axis=-1).reshape(-1, 3).astype(np.float32)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(image points (N, 2) in COLMAP pixel coordinates, object points (N, 3)), or None."""
        gray8 = _to_uint8(gray)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(gray8, (self.columns, self.rows), flags=flags)
        if not found:
            return None
        # cornerSubPix's half-window: a third of the smallest square side seen, so it never
        # reaches the next corner.
        side = np.min(np.linalg.norm(np.diff(corners.reshape(self.rows, self.columns, 2), axis=1), axis=-1))
        half = int(np.clip(side / 3, 2, 11))
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        corners = cv2.cornerSubPix(gray8, corners, (half, half), (-1, -1), criteria)
        return corners.reshape(-1, 2).astype(np.float64) + 0.5, self.object_points()

    def texture(self, texels_per_square: int = 64) -> tuple[np.ndarray, float]:
        """(uint8 image of the board with a one-square white margin, world size of one texel).

        Texel (0, 0)'s corner is at world (-square_size, -square_size): the margin, then the
        squares, whose outer top-left corner is the world origin.
        """
        n_x, n_y = self.columns + 1, self.rows + 1
        j, i = np.mgrid[0:n_y + 2, 0:n_x + 2]
        inside = (i >= 1) & (i <= n_x) & (j >= 1) & (j <= n_y)
        black = inside & ((i + j) % 2 == 0)
        squares = np.where(black, 0, 255).astype(np.uint8)
        image = np.kron(squares, np.ones((texels_per_square, texels_per_square), np.uint8))
        return image, self.square_size / texels_per_square

    def texture_origin(self) -> tuple[float, float]:
        return -self.square_size, -self.square_size


@dataclass(frozen=True)
class CharucoTarget:
    """A ChArUco board (chessboard with ArUco markers in its white squares)."""

    squares_x: int = opt(7, "squares along the board's width", ge=3)
    squares_y: int = opt(5, "squares along the board's height", ge=3)
    square_size: float = opt(1.0, "side of one square in world units (sets the unit of the poses)", gt=0.0)
    marker_size: float = opt(0.7, "side of one ArUco marker, same units as square_size", gt=0.0)
    dictionary: str = opt("DICT_5X5_100", "cv2.aruco predefined dictionary the markers come from")

    def board(self):
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_size,
                                      self.marker_size, dictionary)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(image points (N, 2) in COLMAP pixel coordinates, object points (N, 3)), or None.

        Needs at least 6 corners (a homography's worth with margin).
        """
        board = self.board()
        detector = cv2.aruco.CharucoDetector(board)
        gray8 = _to_uint8(gray)
        corners, ids, marker_corners, _ = detector.detectBoard(gray8)
        if ids is None or len(ids) < 6:
            return None
        # The detector places corners from marker homographies; refine them on the image, with a
        # half-window that stays inside the white gap between a corner and its markers.
        side = np.median([np.linalg.norm(np.diff(m.reshape(4, 2), axis=0), axis=1).mean()
                          for m in marker_corners]) / self.marker_size * self.square_size
        half = int(np.clip(side * (1 - self.marker_size / self.square_size) / 2 - 1, 2, 11))
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        corners = cv2.cornerSubPix(gray8, corners.astype(np.float32), (half, half), (-1, -1), criteria)
        obj, img = board.matchImagePoints(corners, ids)
        return img.reshape(-1, 2).astype(np.float64) + 0.5, obj.reshape(-1, 3).astype(np.float32)

    def texture(self, texels_per_square: int = 64) -> tuple[np.ndarray, float]:
        """(uint8 board image with a one-square white margin, world size of one texel)."""
        t = texels_per_square
        size = ((self.squares_x + 2) * t, (self.squares_y + 2) * t)
        return self.board().generateImage(size, marginSize=t, borderBits=1), self.square_size / t

    def texture_origin(self) -> tuple[float, float]:
        return -self.square_size, -self.square_size


Target = Chessboard | CharucoTarget


@dataclass(frozen=True)
class Calibration:
    camera: Intrinsics
    rms: float  # RMS reprojection error over all used corners, pixels
    used: list[int]  # indices of the images the target was found in
    rotations: list[np.ndarray]  # world-to-camera rotation of each used view
    translations: list[np.ndarray]


def _to_uint8(image: np.ndarray) -> np.ndarray:
    gray = to_gray(image)
    if gray.dtype == np.uint8:
        return gray
    return np.round(gray.astype(np.float64) * 255.0 / max_value(gray.dtype)).astype(np.uint8)


def _camera_of(model: str, K: np.ndarray, dist: np.ndarray, width: int, height: int) -> Intrinsics:
    d = np.concatenate([np.ravel(dist), np.zeros(8)])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    params = {
        "SIMPLE_PINHOLE": (fx, cx, cy),
        "PINHOLE": (fx, fy, cx, cy),
        "SIMPLE_RADIAL": (fx, cx, cy, d[0]),
        "RADIAL": (fx, cx, cy, d[0], d[1]),
        "OPENCV": (fx, fy, cx, cy, *d[:4]),
        "FULL_OPENCV": (fx, fy, cx, cy, *d[:8]),
    }[model]
    return Intrinsics(model, width, height, params)


def calibrate(images: Sequence[np.ndarray], target: Target = Chessboard(),
              model: CalibrationModel = "OPENCV") -> Calibration:
    """Calibrate one camera from images of ``target`` (all the same size).

    Raises ValueError when the target is found in fewer than 3 images.
    """
    if model not in _MODEL_FLAGS:
        raise ValueError(f"cannot calibrate model {model!r}; choose one of {sorted(_MODEL_FLAGS)}")
    sizes = {im.shape[:2] for im in images}
    if len(sizes) != 1:
        raise ValueError(f"calibration images must share one size, got {sorted(sizes)}")
    height, width = sizes.pop()
    image_points, object_points, used = [], [], []
    for index, image in enumerate(images):
        check_image(image)
        found = target.detect(image)
        if found is None:
            logger.info("calibration target not found in image %d", index)
            continue
        image_points.append((found[0] - 0.5).astype(np.float32))  # OpenCV pixel convention
        object_points.append(found[1])
        used.append(index)
    if len(used) < 3:
        raise ValueError(f"calibration target found in {len(used)} images; need at least 3")
    K0 = np.eye(3)  # only the aspect ratio (1) matters to FIX_ASPECT_RATIO without USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(object_points, image_points, (width, height), K0, None,
                                                     flags=_MODEL_FLAGS[model], criteria=criteria)
    camera = _camera_of(model, K, dist, width, height)
    logger.info("calibrated %s from %d views: rms %.3f px", camera.model, len(used), rms)
    return Calibration(camera=camera, rms=float(rms), used=used,
                       rotations=[cv2.Rodrigues(r)[0] for r in rvecs],
                       translations=[np.ravel(t).astype(float) for t in tvecs])


def _supersampled_rays(camera: Intrinsics, n: int) -> np.ndarray:
    """(H*n, W*n, 2) float32 undistorted normalised coordinates of every sub-pixel sample.

    The exact inverse of the distortion is computed at the pixel corners and interpolated
    bilinearly inside each pixel (the distortion is smooth: the error is far below 1e-3 px).
    """
    gx, gy = np.meshgrid(np.arange(camera.width + 1, dtype=np.float64),
                         np.arange(camera.height + 1, dtype=np.float64))
    corners = camera.undistort_pixels(np.stack([gx.ravel(), gy.ravel()], axis=1))
    corners = corners.reshape(camera.height + 1, camera.width + 1, 2).astype(np.float32)
    sub_x = ((np.arange(camera.width * n) + 0.5) / n).astype(np.float32)
    sub_y = ((np.arange(camera.height * n) + 0.5) / n).astype(np.float32)
    map_x, map_y = np.meshgrid(sub_x, sub_y)
    return cv2.remap(corners, map_x, map_y, cv2.INTER_LINEAR)


def render_board_views(target: Target, camera: Intrinsics, poses: Sequence[tuple[np.ndarray, np.ndarray]],
                       supersample: int = 4, background: int = 90, texels_per_square: int = 64) -> list[np.ndarray]:
    """Render uint8 gray views of ``target`` (on world Z = 0) seen by ``camera`` from each (R, t).

    x_cam = R @ X + t (COLMAP convention); the board's texture x axis is world X, its y axis world Y,
    so a camera with R = I in front of it (t_z > 0) sees it unmirrored. Each pixel averages
    ``supersample``^2 samples.
    """
    texture, texel = target.texture(texels_per_square)
    texture = texture.astype(np.float32)
    x0, y0 = target.texture_origin()
    rays = _supersampled_rays(camera, supersample)
    # World plane (X, Y) -> OpenCV texel index coordinates.
    to_texels = np.array([[1 / texel, 0, -x0 / texel - 0.5], [0, 1 / texel, -y0 / texel - 0.5], [0, 0, 1]])
    views = []
    for R, t in poses:
        # Plane Z = 0: ray (x, y, 1) ~ [r1 r2 t] @ (X, Y, 1), so texels ~ to_texels @ inv([r1 r2 t]) @ ray.
        M = to_texels @ np.linalg.inv(np.column_stack([R[:, 0], R[:, 1], t]))
        tex = cv2.perspectiveTransform(rays.reshape(-1, 1, 2), M).reshape(rays.shape)
        # The ray meets the plane in front of the camera when n.t / n.ray > 0 (n: plane normal).
        normal = R[:, 2]
        denominator = rays[..., 0] * normal[0] + rays[..., 1] * normal[1] + normal[2]
        tex[denominator * (normal @ t) <= 0] = -1e6
        samples = cv2.remap(texture, tex[..., 0], tex[..., 1], cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
        pixels = cv2.resize(samples, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
        views.append(np.clip(np.rint(pixels), 0, 255).astype(np.uint8))
    return views
