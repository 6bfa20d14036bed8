"""Camera intrinsics in COLMAP's terms, as the 2D operations change them.

Pixel convention (COLMAP): the centre of the top-left pixel is at (0.5, 0.5), so pixel (row i,
column j) covers the square [j, j+1) x [i, i+1). OpenCV puts that centre at (0, 0); the two differ
by 0.5 in the principal point only, and :meth:`Intrinsics.opencv_K` / :meth:`Intrinsics.from_opencv`
are the one place that converts.

With this convention, resizing an image from (w, h) to (w', h') maps every continuous coordinate
x -> x * w'/w (pixel edges land on pixel edges), so focal lengths and the principal point simply
scale by the same factors; see :meth:`Intrinsics.scaled`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Parameter names in COLMAP order, for every model this package reads and writes.
MODEL_PARAMS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    # fisheye (equidistant: image radius = f x angle, then distortion) and 360-degree panoramas: COLMAP
    # fits and exports them; the pinhole operations below (undistortion, projection) refuse them
    "SIMPLE_FISHEYE": ("f", "cx", "cy"),
    "FISHEYE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "EQUIRECTANGULAR": ("w", "h"),  # the image size: the model has no other parameter
}
#: the models whose distortion follows OpenCV's pinhole formulas (the rest are fisheye or spherical)
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")


@dataclass(frozen=True)
class Intrinsics:
    """A camera model in COLMAP terms: model name, image size and parameters in COLMAP order."""

    model: str
    width: int
    height: int
    params: tuple[float, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.model not in MODEL_PARAMS:
            raise ValueError(f"unsupported camera model {self.model!r}; known: {sorted(MODEL_PARAMS)}")
        object.__setattr__(self, "params", tuple(float(p) for p in self.params))
        if len(self.params) != len(MODEL_PARAMS[self.model]):
            raise ValueError(f"{self.model} takes {len(MODEL_PARAMS[self.model])} params "
                             f"{MODEL_PARAMS[self.model]}, got {len(self.params)}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")

    @classmethod
    def pinhole(cls, fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> Intrinsics:
        return cls("PINHOLE", width, height, (fx, fy, cx, cy))

    def param(self, name: str) -> float:
        return self.params[MODEL_PARAMS[self.model].index(name)]

    @property
    def fx(self) -> float:
        return self.params[0]

    @property
    def fy(self) -> float:
        return self.params[1] if "fy" in MODEL_PARAMS[self.model] else self.params[0]

    @property
    def cx(self) -> float:
        return self.param("cx")

    @property
    def cy(self) -> float:
        return self.param("cy")

    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix in COLMAP's pixel convention."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.opencv_distortion() != 0))

    def opencv_K(self) -> np.ndarray:
        """3x3 calibration matrix in OpenCV's convention (top-left pixel centre at (0, 0))."""
        K = self.K
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        return K

    def opencv_distortion(self) -> np.ndarray:
        """Distortion coefficients as OpenCV orders them: (k1, k2, p1, p2[, k3, k4, k5, k6])."""
        if self.model not in PINHOLE_MODELS:
            raise ValueError(f"{self.model} is not a pinhole camera: OpenCV's pinhole distortion does not apply")
        names = MODEL_PARAMS[self.model]
        p = dict(zip(names, self.params))
        if self.model in ("SIMPLE_PINHOLE", "PINHOLE"):
            return np.zeros(4)
        if self.model == "SIMPLE_RADIAL":
            return np.array([p["k"], 0.0, 0.0, 0.0])
        if self.model == "RADIAL":
            return np.array([p["k1"], p["k2"], 0.0, 0.0])
        return np.array([p[n] for n in names[4:]])

    @classmethod
    def from_opencv(cls, K: np.ndarray, dist: np.ndarray | None, width: int, height: int) -> Intrinsics:
        """The COLMAP camera for an OpenCV matrix and distortion vector (4, 5 or 8 coefficients).

        Picks PINHOLE for no distortion, OPENCV for (k1, k2, p1, p2) and FULL_OPENCV when k3..k6 are
        used; an OpenCV k3 with no rational terms becomes FULL_OPENCV with k4 = k5 = k6 = 0.
        """
        fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5
        d = np.zeros(8) if dist is None else np.ravel(dist).astype(float)
        if d.size not in (4, 5, 8):
            raise ValueError(f"expected 4, 5 or 8 OpenCV distortion coefficients, got {d.size}")
        d = np.concatenate([d, np.zeros(8 - d.size)])
        if not np.any(d):
            return cls.pinhole(fx, fy, cx, cy, width, height)
        if not np.any(d[4:]):
            return cls("OPENCV", width, height, (fx, fy, cx, cy, *d[:4]))
        return cls("FULL_OPENCV", width, height, (fx, fy, cx, cy, *d))

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The camera of this image resized to ``width`` x ``height`` (COLMAP's Camera::Rescale).

        Focal lengths and principal point scale by width'/width and height'/height; a model with
        one focal length takes the mean of the two factors (they differ only by rounding).
        Distortion coefficients act on normalised coordinates and do not change; an equirectangular
        camera's parameters are its size.
        """
        sx, sy = width / self.width, height / self.height
        names = MODEL_PARAMS[self.model]
        params = list(self.params)
        for i, name in enumerate(names):
            if name in ("fx", "cx"):
                params[i] *= sx
            elif name in ("fy", "cy"):
                params[i] *= sy
            elif name == "f":
                params[i] *= 0.5 * (sx + sy)
            elif name in ("w", "h"):
                params[i] = width if name == "w" else height
        return Intrinsics(self.model, width, height, tuple(params))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3), distortion included."""
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        return self.distort_normalized(pts[:, :2] / pts[:, 2:3]) * [self.fx, self.fy] + [self.cx, self.cy]

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply this model's distortion to normalised image coordinates (N, 2) (OpenCV formulas)."""
        k1, k2, p1, p2, k3, k4, k5, k6 = np.concatenate([self.opencv_distortion(), np.zeros(4)])[:8]
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Normalised undistorted coordinates (N, 2) of pixel coordinates (N, 2).

        Inverts :meth:`distort_normalized` by Newton's method (numerical Jacobian), to 1e-12.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        target = (uv - [self.cx, self.cy]) / [self.fx, self.fy]
        if not self.has_distortion:
            return target
        xy = target.copy()
        eps = 1e-7
        for _ in range(30):
            f = self.distort_normalized(xy) - target
            if np.max(np.abs(f)) < 1e-12:
                break
            jx = (self.distort_normalized(xy + [eps, 0.0]) - target - f) / eps
            jy = (self.distort_normalized(xy + [0.0, eps]) - target - f) / eps
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            xy[:, 0] -= (jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det
            xy[:, 1] -= (jx[:, 0] * f[:, 1] - jx[:, 1] * f[:, 0]) / det
        return xy

    def to_pycolmap(self):
        """The equivalent ``pycolmap.Camera``."""
        import pycolmap

        return pycolmap.Camera(model=self.model, width=self.width, height=self.height, params=list(self.params))

    @classmethod
    def from_pycolmap(cls, camera) -> Intrinsics:
        return cls(camera.model.name, int(camera.width), int(camera.height), tuple(camera.params))
