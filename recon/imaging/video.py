"""Video to keyframes: decode with PyAV, drop blurred frames, keep frames spread by parallax.

One pass over the video, on gray frames downscaled (anti-aliased) to ``analysis_size``:

- Sharpness: variance of the Laplacian. Its absolute value depends on the content, so a frame is
  blurred when it falls below ``blur_ratio`` times the median of its ``blur_window`` neighbours on
  each side (motion blur and focus hunting come in short bursts; the median ignores them). The
  decision waits for the following ``blur_window`` frames, which are held in a short queue.
- Parallax: features of the last keyframe (cv2.goodFeaturesToTrack) are tracked through every sharp
  frame with pyramidal Lucas-Kanade (cv2.calcOpticalFlowPyrLK), keeping tracks that pass a
  forward-backward check; the median displacement since the keyframe, as a fraction of the image
  diagonal, is the parallax. A sharp frame whose parallax reaches ``min_parallax`` becomes the next
  keyframe, as does one where fewer than ``min_tracked`` of the tracks survive (the view changed
  faster than tracks could follow: keep overlap).
- ``max_frames``: when more keyframes were found, the ones closest to evenly spaced positions along
  the accumulated parallax are kept.

Frames carrying a display rotation (phone videos) are turned upright.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from PIL import Image

from recon.imaging.resize import resize_to
from recon.options import opt

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class KeyframeOptions:
    min_parallax: float = opt(0.05, "median feature motion since the last keyframe that makes a new one, "
                                    "as a fraction of the image diagonal", gt=0.0, le=1.0)
    max_frames: int = opt(300, "keep at most this many keyframes, evenly spread by motion; 0 = no limit", ge=0)
    blur_ratio: float = opt(0.6, "a frame is blurred when its Laplacian variance is below this fraction of "
                                 "the median of its neighbours", ge=0.0, le=1.0)
    blur_window: int = opt(10, "neighbours on each side whose median sharpness a frame is compared with",
                           ge=1, le=500)
    min_tracked: float = opt(0.4, "a frame where fewer than this fraction of the keyframe's tracks survive "
                                  "becomes a keyframe", ge=0.0, le=1.0)
    analysis_size: int = opt(640, "longest side, in pixels, of the frames the analysis runs on", ge=64, le=4096)
    max_corners: int = opt(500, "features tracked from each keyframe", ge=16, le=10000)
    image_format: Literal["jpg", "png"] = opt("jpg", "format of extracted keyframe images")
    jpeg_quality: int = opt(95, "JPEG quality of extracted keyframes", ge=50, le=100)


@dataclass(frozen=True)
class Keyframe:
    index: int  # position of the frame in decoding order, from 0
    time: float  # presentation time, seconds
    sharpness: float  # variance of the Laplacian at the analysis size
    parallax: float  # median feature motion since the previous keyframe, fraction of the diagonal


def _decode(video_path: str | Path, fmt: str) -> Iterator[tuple[int, float, np.ndarray]]:
    """(index, time in seconds, upright frame as ``fmt``: 'gray' or 'rgb24') for every frame."""
    import av  # imported here: PyAV takes ~0.1 s to load, which every `recon` command would pay

    with av.open(str(video_path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        for index, frame in enumerate(container.decode(stream)):
            image = frame.to_ndarray(format=fmt)
            quarter_turns = round((frame.rotation or 0) / 90) % 4  # counter-clockwise, as displayed
            if quarter_turns:
                image = np.ascontiguousarray(np.rot90(image, quarter_turns))
            yield index, (frame.time if frame.time is not None else index / rate), image


def laplacian_variance(gray: np.ndarray) -> float:
    """Variance of the Laplacian of a gray image (float pixels in [0, 1]): high for sharp frames."""
    data = gray.astype(np.float32) / (255.0 if gray.dtype == np.uint8 else 1.0)
    return float(cv2.Laplacian(data, cv2.CV_32F, ksize=3).var())


class _Tracker:
    """Tracks the last keyframe's features frame to frame; reports parallax and survival."""

    def __init__(self, options: KeyframeOptions, shape: tuple[int, int]):
        self.options = options
        self.diagonal = float(np.hypot(*shape))
        self.min_distance = max(3.0, self.diagonal / 80.0)
        self.start = self.points = np.empty((0, 2), np.float32)
        self.initial = 1
        self.previous = None

    def start_keyframe(self, gray: np.ndarray) -> None:
        """Detect fresh features on a new keyframe and track from there."""
        corners = cv2.goodFeaturesToTrack(gray, self.options.max_corners, qualityLevel=0.01,
                                          minDistance=self.min_distance, blockSize=7)
        self.start = np.empty((0, 2), np.float32) if corners is None else corners.reshape(-1, 2)
        self.points = self.start.copy()
        self.initial = max(len(self.start), 1)
        self.previous = gray

    def update(self, gray: np.ndarray) -> tuple[float, float]:
        """Track into ``gray``; returns (parallax, fraction of the keyframe's tracks alive)."""
        if len(self.start) == 0:
            return 0.0, 0.0
        params = dict(winSize=(21, 21), maxLevel=3,
                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))
        p0 = self.points.reshape(-1, 1, 2)
        p1, ok, _ = cv2.calcOpticalFlowPyrLK(self.previous, gray, p0, None, **params)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gray, self.previous, p1, None, **params)
        good = (ok.ravel() == 1) & (ok_back.ravel() == 1) & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < 1.0)
        self.points, self.start = p1.reshape(-1, 2)[good], self.start[good]
        self.previous = gray
        if len(self.points) == 0:
            return 0.0, 0.0
        motion = np.linalg.norm(self.points - self.start, axis=1)
        return float(np.median(motion)) / self.diagonal, len(self.points) / self.initial


def _spread(keyframes: list[Keyframe], count: int) -> list[Keyframe]:
    """The ``count`` keyframes nearest to evenly spaced positions along the accumulated parallax."""
    travelled = np.cumsum([k.parallax for k in keyframes])
    chosen = sorted({int(np.argmin(np.abs(travelled - target)))
                     for target in np.linspace(travelled[0], travelled[-1], count)})
    out = []
    for position, i in enumerate(chosen):
        motion = travelled[i] - travelled[chosen[position - 1]] if position else 0.0
        out.append(replace(keyframes[i], parallax=float(motion)))
    return out


def select_keyframes(video_path: str | Path, options: KeyframeOptions = KeyframeOptions()) -> list[Keyframe]:
    """Choose keyframes of a video (see the module docstring for how)."""
    window = options.blur_window
    sharpness: list[float] = []
    pending: deque[tuple[int, float, np.ndarray]] = deque()
    keyframes: list[Keyframe] = []
    tracker: _Tracker | None = None
    blurred = 0

    def decide(index: int, time: float, gray: np.ndarray) -> None:
        nonlocal tracker, blurred
        score = sharpness[index]
        neighbours = sharpness[max(0, index - window): index + window + 1]
        if score < options.blur_ratio * float(np.median(neighbours)):
            blurred += 1
            return
        if tracker is None:
            tracker = _Tracker(options, gray.shape)
        if not keyframes:
            parallax, alive = 0.0, 0.0
        else:
            parallax, alive = tracker.update(gray)
            if parallax < options.min_parallax and alive >= options.min_tracked:
                return
        keyframes.append(Keyframe(index=index, time=float(time), sharpness=score, parallax=parallax))
        tracker.start_keyframe(gray)

    total = 0
    for index, time, gray in _decode(video_path, "gray"):
        h, w = gray.shape
        scale = min(1.0, options.analysis_size / max(h, w))
        small = resize_to(gray, max(1, round(w * scale)), max(1, round(h * scale)))
        sharpness.append(laplacian_variance(small))
        pending.append((index, time, small))
        if len(pending) > window:
            decide(*pending.popleft())
        total = index + 1
    while pending:
        decide(*pending.popleft())
    logger.info("%s: %d frames, %d blurred, %d keyframes", Path(video_path).name, total, blurred, len(keyframes))
    if options.max_frames and len(keyframes) > options.max_frames:
        keyframes = _spread(keyframes, options.max_frames)
        logger.info("kept %d keyframes spread by motion (max_frames)", len(keyframes))
    return keyframes


def extract_keyframes(video_path: str | Path, out_dir: str | Path,
                      options: KeyframeOptions = KeyframeOptions()) -> list[Path]:
    """Select keyframes and write them as ``<out_dir>/<video stem>_<frame index>.<format>`` (RGB)."""
    keyframes = select_keyframes(video_path, options)
    wanted = {k.index for k in keyframes}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = Path(video_path).stem
    paths = []
    for index, _, rgb in _decode(video_path, "rgb24"):
        if index in wanted:
            path = out_dir / f"{stem}_{index:06d}.{options.image_format}"
            extra = {"quality": options.jpeg_quality} if options.image_format == "jpg" else {}
            Image.fromarray(rgb).save(path, **extra)
            paths.append(path)
            if len(paths) == len(wanted):
                break
    return paths
