"""Exposure brackets through preprocess (criterion 6): one merged image per view, better than any exposure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import recon
from recon.files import read_json
from recon.sparse.features import FeaturesConfig, extract_sift

TIMES = (1.0, 16.0, 256.0)  # 4 stops apart
VIEWS = 5
SIFT = FeaturesConfig().settings()  # features' defaults


def output(ws: Path, stage: str) -> Path:
    return ws / ".recon" / "cache" / stage / read_json(ws / ".recon" / "state.json")[stage][:16]


def _exposures(photo: np.ndarray, seed: int) -> list[np.ndarray]:
    """A photo lit 8 stops brighter on its left than its right, shot at each of TIMES (noise, gamma, 8 bit)."""
    linear = (photo.astype(np.float32) / 255.0) ** 2.2
    x = np.arange(photo.shape[1], dtype=np.float32)[None, :, None]
    radiance = linear * 2.0 ** (-8.0 / (1.0 + np.exp(-(x - photo.shape[1] / 2) / 15.0)))
    rng = np.random.default_rng(seed)
    shots = []
    for t in TIMES:
        v = np.clip(radiance * t, 0.0, 1.0)
        v = v + rng.normal(0.0, 1.0, v.shape) * np.sqrt(1e-4 * v + 1e-6)
        shots.append(np.rint(np.clip(v, 0.0, 1.0) ** (1 / 2.2) * 255).astype(np.uint8))
    return shots


def _write(path: Path, image: np.ndarray, exposure: float | None = None) -> None:
    exif = Image.Exif()
    if exposure is not None:
        exif.get_ifd(0x8769)[0x829A] = exposure
    Image.fromarray(image).save(path, exif=exif, **({"quality": 95} if path.suffix == ".jpg" else {}))


@pytest.mark.parametrize("group_by, method", [("name", "mertens"), ("exposure", "debevec")])
def test_brackets_merge_into_one_image_per_view(small_scene, tmp_path, group_by, method):
    photos = tmp_path / "photos"
    photos.mkdir()
    names = sorted(p.name for p in (small_scene / "images").iterdir())[:VIEWS]
    singles: dict[str, list[Path]] = {}
    for v, name in enumerate(names):
        shots = _exposures(np.asarray(Image.open(small_scene / "images" / name)), seed=v)
        stem = Path(name).stem
        for k, (shot, t) in enumerate(zip(shots, TIMES)):
            # name: view_000_ev-4.png ...; exposure: shot_000.jpg ... in capture order, EXIF times
            path = photos / (f"{stem}_ev{4 * k - 4:+d}.png" if group_by == "name" else f"shot_{3 * v + k:03d}.jpg")
            _write(path, shot, t / 1000 if group_by == "exposure" else None)
            singles.setdefault(name, []).append(path)
    ws = tmp_path / "ws"
    result = recon.run({"until": "features", "preprocess": {"brackets": {"group_by": group_by, "method": method}}},
                       images=str(photos), workspace=str(ws))
    assert result.summaries["preprocess"]["merged_brackets"] == 2 * VIEWS
    out = output(ws, "preprocess")
    listing = read_json(out / "images.json")
    expected = [f"{Path(n).stem}.png" for n in names] if group_by == "name" else \
        [f"shot_{3 * v:03d}.jpg" for v in range(VIEWS)]
    assert [i["name"] for i in listing["images"]] == expected
    assert all(len(i["sources"]) == 3 for i in listing["images"])
    assert result.summaries["features"]["images"] == VIEWS
    figures = []
    for name, image in zip(names, listing["images"]):
        merged = out / "images" / image["name"]
        assert np.array_equal(np.asarray(Image.open(merged)), np.asarray(Image.open(out / "images_geometric" /
                                                                                       image["name"])))
        counts = [len(extract_sift(p, SIFT)[0]) for p in singles[name]]
        figures.append((counts, len(extract_sift(merged, SIFT)[0])))
    print(f"{group_by}/{method}: (features of each exposure, of the merged image) per view: {figures}")
    assert all(merged >= max(counts) for counts, merged in figures)
