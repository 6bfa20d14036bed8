"""Camera layouts of the zoo's scenes: where the photos are taken from, as a path of poses.

Each layout maps a position ``s`` on its path (0 .. views-1 for the regular views) to a pose, with a
small seeded jitter as a hand-held or flown camera has. Hold-out views sit halfway between two
regular ones (``s`` + 0.5), with their own jitter, so adding hold-out views never moves the regular
ones (as recon.synth.cameras does for the seeded scene).

- :class:`Orbit`: around a target on a circle (a full turn, or an arc), looking at the target.
- :class:`Walk`: along a straight line, looking in a fixed direction: sideways past a facade, or
  forward down a street.
- :class:`Grid`: an aerial survey: nadir views on flight lines flown back and forth, spaced for a
  given forward and side overlap of the footprints on the ground.
- :class:`Around`: a walk around a building with a phone: eye height, facing each facade in turn and
  turning at the corners, unevenly spaced steps.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from recon.eval.groundtruth import Camera
from recon.synth.cameras import look_at


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@dataclasses.dataclass(frozen=True)
class Orbit:
    target: tuple[float, float, float]
    radius: float
    elevation_deg: float
    arc_deg: float = 360.0  # below 360: an open arc from start_deg, first and last views at its ends
    start_deg: float = 0.0

    @property
    def closed(self) -> bool:
        return self.arc_deg >= 360.0

    def pose(self, s: float, views: int, rng: np.random.Generator, footprint) -> tuple[np.ndarray, np.ndarray]:
        step = self.arc_deg / (views if self.closed else max(views - 1, 1))
        azimuth = np.radians(self.start_deg + step * s + rng.uniform(-1.5, 1.5))
        elevation = np.radians(self.elevation_deg + rng.uniform(-2.0, 2.0))
        radius = self.radius * rng.uniform(0.96, 1.04)
        target = np.asarray(self.target, float)
        center = target + radius * np.array([np.cos(elevation) * np.cos(azimuth),
                                             np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        return look_at(center, target)


@dataclasses.dataclass(frozen=True)
class Walk:
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    direction: tuple[float, float, float]  # where the camera looks (world z up stays image up)
    sway: float = 0.04  # position jitter (m) and ~1.5 degrees of yaw and pitch jitter
    closed: bool = False

    def pose(self, s: float, views: int, rng: np.random.Generator, footprint) -> tuple[np.ndarray, np.ndarray]:
        frac = s / max(views - 1, 1)
        start, end = np.asarray(self.start, float), np.asarray(self.end, float)
        center = start + frac * (end - start) + rng.uniform(-self.sway, self.sway, 3)
        R, _ = look_at(center, center + np.asarray(self.direction, float))
        yaw, pitch = np.radians(rng.uniform(-1.5, 1.5, 2))
        R = _rotation_about(np.array([0.0, 1.0, 0.0]), yaw) @ _rotation_about(np.array([1.0, 0.0, 0.0]), pitch) @ R
        return R, -R @ center


@dataclasses.dataclass(frozen=True)
class Grid:
    """Flight lines along world y, side by side along x, centred on ``centre`` at ``height`` above it;
    image x along world x. Views fill the lines in order (the last line may be shorter)."""

    centre: tuple[float, float, float]
    height: float
    lines: int
    forward_overlap: float = 0.7
    side_overlap: float = 0.6
    closed: bool = False

    def pose(self, s: float, views: int, rng: np.random.Generator, footprint) -> tuple[np.ndarray, np.ndarray]:
        per_line = -(-views // self.lines)
        step_x = (1 - self.side_overlap) * footprint[0] * self.height
        step_y = (1 - self.forward_overlap) * footprint[1] * self.height
        i = int(np.floor(s))
        a, b = self._spot(i, per_line, step_x, step_y), self._spot(i + 1, per_line, step_x, step_y)
        center = a + (s - i) * (b - a) + np.concatenate([rng.uniform(-0.01, 0.01, 2) * self.height,
                                                        [rng.uniform(-0.02, 0.02) * self.height]])
        R = np.diag([1.0, -1.0, -1.0])  # looking straight down, image x = world x, image y = world -y
        tilt = _rotation_about(np.array([1.0, 0.0, 0.0]), np.radians(rng.uniform(-1.5, 1.5)))
        yaw = _rotation_about(np.array([0.0, 0.0, 1.0]), np.radians(rng.uniform(-2.0, 2.0)))
        R = tilt @ yaw @ R
        return R, -R @ center

    def _spot(self, k: int, per_line: int, step_x: float, step_y: float) -> np.ndarray:
        line, along = divmod(k, per_line)
        if line % 2:
            along = per_line - 1 - along  # fly back and forth
        x = (line - (self.lines - 1) / 2) * step_x
        y = (along - (per_line - 1) / 2) * step_y
        return np.asarray(self.centre, float) + [x, y, self.height]


@dataclasses.dataclass(frozen=True)
class Around:
    """A closed walk around a rectangular building (footprint ``size`` centred on ``centre``): on the
    footprint grown by ``distance``, corners rounded, at eye ``height``. The camera looks at the nearest
    point of the footprint shrunk to ``facing`` of its size at ``aim`` height: it faces each facade
    along the sides and turns through the corner on the corner's arc (``facing`` 0: always at the
    centre). Steps along the path vary by ``unevenness`` (a fraction of a step), as a person's do."""

    centre: tuple[float, float]
    size: tuple[float, float]
    distance: float
    height: float = 1.6
    aim: float = 3.0
    facing: float = 0.6
    unevenness: float = 0.3
    closed: bool = True

    def pose(self, s: float, views: int, rng: np.random.Generator, footprint) -> tuple[np.ndarray, np.ndarray]:
        sx, sy = self.size
        d = self.distance
        sides = [sx, np.pi / 2 * d, sy, np.pi / 2 * d, sx, np.pi / 2 * d, sy, np.pi / 2 * d]
        length = (s + rng.uniform(-self.unevenness, self.unevenness) / 2) / views * sum(sides) % sum(sides)
        # walk counter-clockwise from the south-west corner's end along the south side (y = -sy / 2 - d)
        corners = [(sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2), (-sx / 2, -sy / 2)]
        for k, piece in enumerate(sides):
            if length <= piece or k == len(sides) - 1:
                break
            length -= piece
        corner = np.array(corners[k // 2])
        heading = k // 2 * np.pi / 2  # direction of travel along side k // 2
        if k % 2 == 0:  # a straight side, ending at ``corner``
            along = np.array([np.cos(heading), np.sin(heading)])
            offset = corner + d * np.array([np.sin(heading), -np.cos(heading)]) - along * (piece - length)
        else:  # the arc round ``corner``
            angle = heading - np.pi / 2 + length / d
            offset = corner + d * np.array([np.cos(angle), np.sin(angle)])
        xy = np.asarray(self.centre, float) + offset + rng.uniform(-0.15, 0.15, 2)
        inner = np.clip(offset, -np.array([sx, sy]) * self.facing / 2, np.array([sx, sy]) * self.facing / 2)
        center = np.array([*xy, self.height + rng.uniform(-0.1, 0.1)])
        target = np.array([*(np.asarray(self.centre, float) + inner), self.aim + rng.uniform(-0.3, 0.3)])
        R, _ = look_at(center, target)
        yaw = np.radians(rng.uniform(-3.0, 3.0))
        R = _rotation_about(np.array([0.0, 1.0, 0.0]), yaw) @ R
        return R, -R @ center


Layout = Orbit | Walk | Grid | Around


def layout_cameras(layout: Layout, views: int, holdout: int, width: int, height: int, focal_factor: float,
                   seed: int = 0, image_format: str = "jpg") -> tuple[dict[str, Camera], dict[str, Camera]]:
    """Regular and hold-out cameras keyed by image name (``view_000.jpg``..., ``holdout_000.jpg``...);
    fx = fy = ``focal_factor`` x width, principal point at the image centre."""
    if views < 2 or holdout < 0:
        raise ValueError("need views >= 2 and holdout >= 0")
    f = focal_factor * width
    K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    footprint = (width / f, height / f)
    regular_s = np.arange(views, dtype=float)
    holdout_s = np.floor(np.arange(holdout) * views / max(holdout, 1)) + 0.5
    if not layout.closed:
        holdout_s = np.minimum(holdout_s, views - 1.5)
    out = []
    for stream, params in ((1, regular_s), (2, holdout_s)):
        rng = np.random.default_rng([seed, stream])
        out.append([Camera(K.copy(), *layout.pose(s, views, rng, footprint), width, height) for s in params])
    regular = {f"view_{i:03d}.{image_format}": c for i, c in enumerate(out[0])}
    held = {f"holdout_{i:03d}.{image_format}": c for i, c in enumerate(out[1])}
    return regular, held
