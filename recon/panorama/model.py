"""The geometry of a panorama: the cameras that made it and how directions map to its pixels.

Rotations are camera-to-panorama: a ray ``d`` in photo ``i``'s camera frame (x right, y down,
z forward, as in COLMAP) points along ``R_i @ d`` in the panorama frame, whose y axis is the
panorama's "down" after wave correction. A panorama-frame direction (x, y, z) projects as OpenCV's
warpers do (``cv2.PyRotationWarper``), with ``s`` the panorama's scale in pixels per radian:

- spherical:   u = s atan2(x, z),  v = s (pi - acos(y / |d|))
- cylindrical: u = s atan2(x, z),  v = s y / hypot(x, z)
- plane:       u = s x / z,        v = s y / z

and pixel column ``u - u0``, row ``v - v0`` (integers at pixel centres in OpenCV's convention).
Pixel coordinates at the API follow recon's (COLMAP) convention: the top-left pixel's centre is at
(0.5, 0.5). A full-circle panorama spans exactly 2 pi: ``width == 2 pi s`` and columns wrap.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from recon.geometry.transforms import apply_matrix


@dataclasses.dataclass(frozen=True)
class PanoramaModel:
    projection: str  # spherical | cylindrical | plane
    scale: float  # pixels per radian (the focal length of a plane projection)
    width: int
    height: int
    u0: int  # projection coordinate u of pixel column 0
    v0: int  # projection coordinate v of pixel row 0
    full_circle: bool  # the panorama covers 360 deg and wraps: width == 2 pi scale
    rotations: np.ndarray  # (n, 3, 3) camera-to-panorama, one per stitched photo
    focals: np.ndarray  # (n,) focal lengths in pixels of the photos at full resolution
    principal: np.ndarray  # (n, 2) principal points, COLMAP convention, full resolution

    def to_pixel(self, dirs: np.ndarray, camera: int | None = None) -> np.ndarray:
        """Pixel coordinates (N, 2) of directions (N, 3) given in the panorama frame, or in the frame
        of stitched photo number ``camera``. Spherical and cylindrical columns are taken within half a
        turn of the panorama's middle (a full circle's fall in [0, width)); a plane panorama gives
        NaN for directions behind it."""
        d = np.asarray(dirs, np.float64).reshape(-1, 3)
        if camera is not None:
            d = apply_matrix(self.rotations[camera], d)
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        s = self.scale
        if self.projection == "plane":
            with np.errstate(divide="ignore", invalid="ignore"):
                u, v = s * x / z, s * y / z
            u[z <= 0] = np.nan
            v[z <= 0] = np.nan
        else:
            u = s * np.arctan2(x, z)
            if self.projection == "spherical":
                v = s * (np.pi - np.arccos(np.clip(y / np.linalg.norm(d, axis=1), -1.0, 1.0)))
            else:
                v = s * y / np.hypot(x, z)
        col = u - self.u0
        if self.projection != "plane":  # u is periodic: take the turn nearest the panorama's middle
            period, middle = 2 * np.pi * s, (self.width - 1) / 2
            col = np.mod(col - middle + period / 2, period) - period / 2 + middle
        return np.column_stack([col + 0.5, v - self.v0 + 0.5])

    def to_direction(self, pixels: np.ndarray) -> np.ndarray:
        """Unit panorama-frame directions (N, 3) seen at pixel coordinates (N, 2)."""
        p = np.asarray(pixels, np.float64).reshape(-1, 2)
        u = (p[:, 0] - 0.5 + self.u0) / self.scale
        v = (p[:, 1] - 0.5 + self.v0) / self.scale
        if self.projection == "plane":
            d = np.column_stack([u, v, np.ones_like(u)])
        elif self.projection == "spherical":
            sin_v = np.sin(np.pi - v)
            d = np.column_stack([sin_v * np.sin(u), np.cos(np.pi - v), sin_v * np.cos(u)])
        else:
            d = np.column_stack([np.sin(u), v, np.cos(u)])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def camera_pixel(self, camera: int, pixels: np.ndarray) -> np.ndarray:
        """Panorama pixel coordinates (N, 2) of pixels (N, 2) of stitched photo ``camera`` (both in
        COLMAP convention, the photo's at full resolution)."""
        p = np.asarray(pixels, np.float64).reshape(-1, 2)
        rays = np.column_stack([(p - self.principal[camera]) / self.focals[camera], np.ones(len(p))])
        return self.to_pixel(rays, camera)

    def as_dict(self) -> dict:
        """JSON-ready; :meth:`from_dict` reads it back."""
        return {"projection": self.projection, "scale": self.scale, "width": self.width, "height": self.height,
                "u0": self.u0, "v0": self.v0, "full_circle": self.full_circle,
                "cameras": [{"focal": float(f), "principal": c.tolist(), "rotation": R.tolist()}
                            for f, c, R in zip(self.focals, self.principal, self.rotations)]}

    @classmethod
    def from_dict(cls, data: dict) -> PanoramaModel:
        cams = data["cameras"]
        return cls(data["projection"], float(data["scale"]), int(data["width"]), int(data["height"]),
                   int(data["u0"]), int(data["v0"]), bool(data["full_circle"]),
                   np.array([c["rotation"] for c in cams], float).reshape(-1, 3, 3),
                   np.array([c["focal"] for c in cams], float), np.array([c["principal"] for c in cams], float))
