"""Keyframe selection from video (criterion 5): no blurred frame picked, keyframes spread by parallax."""

import av
import cv2
import numpy as np
import pytest
import skimage.data
from PIL import Image

from recon.imaging.video import KeyframeOptions, extract_keyframes, laplacian_variance, select_keyframes

WIDTH, HEIGHT, FRAMES = 320, 240, 90
DIAGONAL = float(np.hypot(WIDTH, HEIGHT))  # 400 px
BLURRED = {5, 12, 13, 14, 30, 44, 45, 52, 60, 61, 70, 77, 85}


def _pan_positions() -> np.ndarray:
    """x offset of each frame: 2 px per frame for the first half, 7 px per frame after."""
    speed = np.where(np.arange(FRAMES) < FRAMES // 2, 2.0, 7.0)
    return 10.0 + np.concatenate([[0.0], np.cumsum(speed)[:-1]])


def _write_video(path, frames, rate=30, rotation=0):
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=rate)
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": "18"}
        if rotation:
            stream.set_display_rotation(rotation)
        for frame in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


@pytest.fixture(scope="module")
def pan_video(tmp_path_factory):
    """A camera panning over a photo at two speeds; some frames (BLURRED) Gaussian-blurred."""
    photo = skimage.data.astronaut()
    canvas = np.hstack([photo, photo[:, ::-1], photo])
    frames = []
    for i, x in enumerate(_pan_positions()):
        frame = cv2.warpAffine(canvas, np.float32([[1, 0, -x], [0, 1, -100]]), (WIDTH, HEIGHT),
                               flags=cv2.INTER_LINEAR)
        frames.append(cv2.GaussianBlur(frame, (0, 0), 2.5) if i in BLURRED else frame)
    path = tmp_path_factory.mktemp("video") / "pan.mp4"
    _write_video(path, frames)
    return path


def test_keyframes_skip_blurred_frames_and_are_spread_by_parallax(pan_video):
    options = KeyframeOptions(min_parallax=0.05, max_frames=0)  # 0.05 x 400 px = 20 px
    keyframes = select_keyframes(pan_video, options)
    indices = [k.index for k in keyframes]
    x = _pan_positions()
    spacing = np.diff(x[indices])
    measured = np.array([k.parallax for k in keyframes[1:]]) * DIAGONAL
    # The same number of frames taken evenly in time, for comparison.
    uniform = np.linspace(0, FRAMES - 1, len(indices)).round().astype(int)
    uniform_spacing = np.diff(x[uniform])
    print(f"keyframes {indices}\ntrue spacing (px) {spacing.tolist()}\nmeasured parallax (px) "
          f"{measured.round(1).tolist()}\nevenly in time: spacing {uniform_spacing.tolist()}")
    assert not set(indices) & BLURRED
    assert indices[0] == 0 and len(indices) >= 12
    assert spacing.min() >= 0.9 * 20 and spacing.max() <= 1.5 * 20
    assert np.abs(measured - spacing).max() < 1.5  # parallax measured by the tracks is the true motion
    assert uniform_spacing.max() / uniform_spacing.min() > 2.5  # what parallax-based selection avoids


def test_blurred_frames_score_below_their_neighbours(pan_video):
    options = KeyframeOptions(min_parallax=0.001, max_frames=0)  # every sharp frame is a keyframe
    picked = {k.index for k in select_keyframes(pan_video, options)}
    assert picked == set(range(FRAMES)) - BLURRED
    sharp = np.zeros((64, 64), np.uint8)
    sharp[::2] = 255
    assert laplacian_variance(cv2.GaussianBlur(sharp, (0, 0), 2.0)) < 0.1 * laplacian_variance(sharp)


def test_max_frames_keeps_keyframes_spread_by_motion(pan_video):
    keyframes = select_keyframes(pan_video, KeyframeOptions(min_parallax=0.02, max_frames=6))
    indices = [k.index for k in keyframes]
    spacing = np.diff(_pan_positions()[indices])
    print(f"max_frames=6: keyframes {indices}, spacing {spacing.tolist()}")
    assert len(indices) == 6 and not set(indices) & BLURRED
    assert spacing.max() / spacing.min() < 1.5
    assert sum(k.parallax for k in keyframes) * DIAGONAL == pytest.approx(spacing.sum(), abs=4.0)


def test_extract_writes_upright_frames(tmp_path):
    """A video with a 90 degree display rotation (phone held upright) comes out upright."""
    frame = np.full((48, 64, 3), 40, np.uint8)
    frame[:8, :16] = 250  # a bright block top-left in the stored frame
    video = tmp_path / "phone.mp4"
    _write_video(video, [frame] * 3, rate=10, rotation=90)
    paths = extract_keyframes(video, tmp_path / "frames", KeyframeOptions(image_format="png"))
    assert [p.name for p in paths] == ["phone_000000.png"]
    image = np.asarray(Image.open(paths[0]))
    assert image.shape == (64, 48, 3)
    expected = np.rot90(frame)  # counter-clockwise, as the display matrix says
    assert np.abs(image.astype(int) - expected).mean() < 6
