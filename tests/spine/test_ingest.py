"""ingest: odd photo files are normalised or skipped with a clear message; cameras grouped sensibly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import recon
from recon.files import read_json
from recon.stage import StageError


def ingest(images: Path, ws: Path, **cfg) -> dict:
    recon.run({"until": "ingest", **({"ingest": cfg} if cfg else {})}, images=str(images), workspace=str(ws))
    return read_json(ws / ".recon" / "cache" / "ingest" / _current(ws) / "images.json")


def _current(ws: Path) -> str:
    return read_json(ws / ".recon" / "state.json")["ingest"][:16]


@pytest.fixture
def photo(small_scene) -> np.ndarray:
    return np.asarray(Image.open(small_scene / "images" / "view_000.jpg"))


def test_odd_formats_become_upright_8bit(tmp_path, photo):
    src = tmp_path / "in"
    src.mkdir()
    Image.fromarray(photo).save(src / "a_rgb.jpg", quality=95)
    Image.fromarray(photo).convert("L").save(src / "b_gray.png")
    Image.fromarray(photo[..., 0].astype(np.uint16) * 257).save(src / "c_16bit.png")
    Image.fromarray(photo).convert("RGBA").save(src / "d_rgba.png")
    Image.fromarray(photo).convert("CMYK").save(src / "e_cmyk.jpg")
    rotated = Image.fromarray(photo).rotate(90, expand=True)  # stored sideways, EXIF says rotate back
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 degrees clockwise to display"
    rotated.save(src / "f_rot.jpg", exif=exif, quality=95)
    (src / "notes.txt").write_text("not a photo")
    listing = ingest(src, tmp_path / "ws")
    by_name = {i["name"]: i for i in listing["images"]}
    assert sorted(by_name) == ["a_rgb.jpg", "b_gray.png", "c_16bit.png", "d_rgba.png", "e_cmyk.jpg", "f_rot.jpg"]
    assert listing["skipped"] == [str(src / "notes.txt")]
    out = tmp_path / "ws" / "images"
    for name, info in by_name.items():
        img = Image.open(out / name)
        assert img.mode in ("L", "RGB"), name
        assert img.size == (info["width"], info["height"]) == (photo.shape[1], photo.shape[0]), name
    assert by_name["a_rgb.jpg"]["converted"] is False and (out / "a_rgb.jpg").is_symlink()
    assert np.asarray(Image.open(out / "c_16bit.png")).max() == photo[..., 0].max()
    upright = np.asarray(Image.open(out / "f_rot.jpg").convert("RGB")).astype(int)
    assert np.abs(upright - photo).mean() < 4  # the EXIF rotation was applied


def test_corrupt_and_empty_files_are_skipped_with_reason(tmp_path, photo):
    src = tmp_path / "in"
    src.mkdir()
    for i in range(3):
        Image.fromarray(np.roll(photo, 7 * i, axis=1)).save(src / f"ok{i}.jpg")
    good = (src / "ok0.jpg").read_bytes()
    (src / "truncated.jpg").write_bytes(good[: len(good) // 3])
    (src / "empty.png").write_bytes(b"")
    listing = ingest(src, tmp_path / "ws")
    assert [i["name"] for i in listing["images"]] == ["ok0.jpg", "ok1.jpg", "ok2.jpg"]
    reasons = " ".join(listing["skipped"])
    assert "empty.png: empty file (0 bytes)" in reasons
    assert "truncated.jpg: cannot read image" in reasons


def test_empty_folder_is_a_clear_error(tmp_path):
    (tmp_path / "in").mkdir()
    with pytest.raises(StageError, match=r"holds no JPEG, PNG or TIFF photos"):
        ingest(tmp_path / "in", tmp_path / "ws")
    with pytest.raises(StageError, match=r"is not a folder"):
        ingest(tmp_path / "missing", tmp_path / "ws")


def test_cameras_grouped_by_folder_and_size_with_exif_focal(tmp_path, small_scene, photo):
    src = tmp_path / "in"
    (src / "cam_a").mkdir(parents=True)
    (src / "cam_b").mkdir()
    for name in ("view_000.jpg", "view_001.jpg"):
        (src / "cam_a" / name).write_bytes((small_scene / "images" / name).read_bytes())
    Image.fromarray(photo).save(src / "cam_b" / "x.jpg")
    Image.fromarray(photo[:200, :300]).save(src / "cam_b" / "y.jpg")  # other size: its own camera
    (src / "cam_b" / "dup.jpg").write_bytes((src / "cam_b" / "x.jpg").read_bytes())
    listing = ingest(src, tmp_path / "ws")
    cams = {c["id"]: c for c in listing["cameras"]}
    by_name = {i["name"]: i for i in listing["images"]}
    assert by_name["cam_a/view_000.jpg"]["camera"] == by_name["cam_a/view_001.jpg"]["camera"]
    assert len({by_name[n]["camera"] for n in ("cam_b/x.jpg", "cam_b/y.jpg", "cam_b/dup.jpg")}) == 3
    K = np.array(read_json(small_scene / "gt" / "cameras.json")["frames"][0]["K"])
    cam_a = cams[by_name["cam_a/view_000.jpg"]["camera"]]
    assert cam_a["prior_focal"] and abs(cam_a["focal"] - K[0, 0]) < 0.01 * K[0, 0]
    assert not cams[by_name["cam_b/x.jpg"]["camera"]]["prior_focal"]
    assert listing["duplicates"] == [["cam_b/dup.jpg", "cam_b/x.jpg"]]
