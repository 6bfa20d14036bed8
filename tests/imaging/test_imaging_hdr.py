"""Exposure brackets (criterion 6): merging rendered brackets, and grouping files into brackets."""

import cv2
import numpy as np
import pytest
import skimage.data
from PIL import Image

from recon.imaging.hdr import group_by_exposure, group_by_name, merge_brackets

TIMES = (1.0, 16.0, 256.0)  # 4 stops apart
ANGLE, ZOOM, SHIFT = 0.08, 0.97, (20.0, -10.0)
HOMOGRAPHY = np.array([[ZOOM * np.cos(ANGLE), -ZOOM * np.sin(ANGLE), SHIFT[0]],
                       [ZOOM * np.sin(ANGLE), ZOOM * np.cos(ANGLE), SHIFT[1]], [0.0, 0.0, 1.0]])


def _radiance() -> np.ndarray:
    """Linear radiance of a photo lit 8 stops brighter on the left than on the right."""
    linear = (skimage.data.astronaut().astype(np.float32) / 255.0) ** 2.2
    x = np.arange(linear.shape[1], dtype=np.float32)[None, :]
    light = 2.0 ** (-8.0 / (1.0 + np.exp(-(x - linear.shape[1] / 2) / 15.0)))
    return linear * light[..., None]


def _expose(radiance: np.ndarray, t: float, seed: int) -> np.ndarray:
    """Clip at full well, add shot and read noise, apply a 1/2.2 gamma, quantise to 8 bits."""
    v = np.clip(radiance * t, 0.0, 1.0)
    v = v + np.random.default_rng(seed).normal(0.0, 1.0, v.shape) * np.sqrt(1e-4 * v + 1e-6)
    return np.rint(np.clip(v, 0.0, 1.0) ** (1 / 2.2) * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def brackets() -> tuple[list[np.ndarray], list[np.ndarray]]:
    rad = _radiance()
    warped = cv2.warpPerspective(rad, HOMOGRAPHY, rad.shape[1::-1], flags=cv2.INTER_LINEAR)
    return ([_expose(rad, t, i) for i, t in enumerate(TIMES)],
            [_expose(warped, t, 10 + i) for i, t in enumerate(TIMES)])


def _features(sift, image: np.ndarray):
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    return sift.extract(gray)


def _correct_matches(fa, fb) -> int:
    """Ratio-test matches (0.8) that the true homography confirms within 3 px."""
    (ka, da), (kb, db) = fa, fb
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da.astype(np.float32), db.astype(np.float32), k=2)
    good = [m for m, n in pairs if m.distance < 0.8 * n.distance]
    pa = ka[[m.queryIdx for m in good], :2].astype(np.float64)
    pb = kb[[m.trainIdx for m in good], :2].astype(np.float64)
    # COLMAP keypoints use the 0.5 pixel-centre convention; the homography acts on OpenCV indices.
    projected = cv2.perspectiveTransform((pa - 0.5).reshape(-1, 1, 2), HOMOGRAPHY).reshape(-1, 2) + 0.5
    return int((np.linalg.norm(projected - pb, axis=1) < 3.0).sum())


@pytest.fixture(scope="module")
def singles(brackets, sift) -> list[tuple[int, int]]:
    """(features in view A, correct matches A-B) for each exposure alone."""
    figures = []
    for a, b in zip(*brackets):
        fa, fb = _features(sift, a), _features(sift, b)
        figures.append((len(fa[0]), _correct_matches(fa, fb)))
    return figures


@pytest.mark.parametrize("method", ["mertens", "debevec"])
def test_merged_bracket_beats_the_best_single_exposure(brackets, singles, sift, method):
    view_a, view_b = brackets
    merged_a = merge_brackets(view_a, TIMES, method=method)
    merged_b = merge_brackets(view_b, TIMES, method=method)
    assert merged_a.dtype == np.uint8 and merged_a.shape == view_a[0].shape
    fa, fb = _features(sift, merged_a), _features(sift, merged_b)
    count, correct = len(fa[0]), _correct_matches(fa, fb)
    print(f"{method}: singles (features, correct matches) {singles}; merged ({count}, {correct})")
    assert count >= max(s[0] for s in singles)
    assert correct >= max(s[1] for s in singles)


def test_merge_keeps_uint16_and_gray():
    rad = _radiance()[::4, ::4].mean(axis=2)
    shots = [(np.clip(rad * t, 0, 1) ** (1 / 2.2) * 65535).astype(np.uint16) for t in TIMES]
    merged = merge_brackets(shots, method="mertens", align=False)
    assert merged.dtype == np.uint16 and merged.shape == rad.shape
    # The dark right side is brighter than in the shortest exposure, the bright left side darker
    # than in the longest: the fused image takes each region from a well-exposed shot.
    w = rad.shape[1]
    assert merged[:, -w // 4:].mean() > shots[0][:, -w // 4:].mean()
    assert merged[:, :w // 4].mean() < shots[2][:, :w // 4].mean()
    with pytest.raises(ValueError):
        merge_brackets(shots, TIMES, method="debevec")


def test_alignment_undoes_a_handheld_shift():
    """Brackets whose outer shots moved by a few pixels merge like the still ones."""
    rad = _radiance()
    shots = [_expose(rad, t, i) for i, t in enumerate(TIMES)]

    def crop(image, dy, dx):  # the camera moved: the same scene seen 16 - d pixels from the edge
        return image[16 + dy:image.shape[0] - 16 + dy, 16 + dx:image.shape[1] - 16 + dx]

    still = [crop(s, 0, 0) for s in shots]
    moved = [crop(shots[0], 3, -4), still[1], crop(shots[2], -2, 5)]
    reference = merge_brackets(still, method="mertens", align=False)
    err = {align: np.abs(merge_brackets(moved, method="mertens", align=align)[8:-8, 8:-8].astype(int)
                         - reference[8:-8, 8:-8]).mean() for align in (True, False)}
    print(f"mean abs difference to the still merge: aligned {err[True]:.2f}, not aligned {err[False]:.2f}")
    assert err[True] < 0.05 * err[False]  # what remains: the few black border pixels a shift exposes


def _write(path, t: float | None) -> None:
    exif = Image.Exif()
    if t is not None:
        exif.get_ifd(0x8769)[0x829A] = t
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(path, exif=exif)


def test_group_by_exposure_time(tmp_path):
    times = [1 / 100, 1 / 400, 1 / 25] * 2 + [1 / 100, 1 / 400]
    paths = []
    for i, t in enumerate(times):
        paths.append(tmp_path / f"IMG_{i:04d}.jpg")
        _write(paths[-1], t)
    brackets = group_by_exposure(paths)
    assert [len(b.paths) for b in brackets] == [3, 3, 2]
    assert brackets[1].view == "IMG_0003" and brackets[1].exposure_times == pytest.approx(times[3:6])
    assert [len(b.paths) for b in group_by_exposure(paths, size=2)] == [2, 2, 2, 2]
    _write(tmp_path / "plain.jpg", None)
    with pytest.raises(ValueError):
        group_by_exposure([tmp_path / "plain.jpg"])


def test_group_by_name(tmp_path):
    names = ["hall_ev-2.jpg", "hall_ev0.jpg", "hall_ev+2.jpg", "door_ev-2.jpg", "door_ev0.jpg"]
    for name in names:
        _write(tmp_path / name, None)
    brackets = group_by_name([tmp_path / n for n in names], r"(?P<view>.+)_ev[-+]?\d+")
    assert [(b.view, len(b.paths)) for b in brackets] == [("hall", 3), ("door", 2)]
    assert brackets[0].exposure_times is None
    with pytest.raises(ValueError):
        group_by_name([tmp_path / "hall_ev0.jpg"], r"(.+)_bracket\d")
