"""preprocess: config validation, the cache, what each output folder holds, cameras and masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import recon
from recon.config import ConfigError
from recon.files import read_json
from recon.pipeline import load_config
from recon.sparse.features import load_features
from recon.stage import StageError
from recon.stages import preprocess as preprocess_stage


def output(ws: Path, stage: str) -> Path:
    """The output folder of ``stage``'s current run in workspace ``ws``."""
    return ws / ".recon" / "cache" / stage / read_json(ws / ".recon" / "state.json")[stage][:16]


def pixels(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path))


def config_error(data: dict) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(data)
    return str(info.value)


def test_ops_validate_with_paths_naming_the_key():
    assert config_error({"preprocess": {"ops": [{"op": "resize", "scale": 0.5}, {"op": "bilateral", "sigma": 2}]}}) \
        == "preprocess.ops[1].sigma: unknown key; did you mean 'sigma_space'?"
    assert config_error({"preprocess": {"ops": [{"op": "clahee"}]}}) == \
        "preprocess.ops[0].op: unknown operation 'clahee'; did you mean 'clahe'?"
    assert config_error({"preprocess": {"ops": [{"op": "resize", "scale": 0}]}}) == \
        "preprocess.ops[0].scale: must be > 0.0; got 0"
    assert config_error({"preprocess": {"ops": [{"op": "clahe", "tiles": "many"}]}}) == \
        "preprocess.ops[0].tiles: expected an integer, got a string 'many'"
    assert config_error({"preprocess": {"ops": ["clahe"]}}).startswith("preprocess.ops[0]: expected a mapping")
    assert config_error({"preprocess": {"ops": [{"clip_limit": 3}]}}).startswith("preprocess.ops[0]: no `op` key")
    assert config_error({"preprocess": {"brackets": {"method": "reinhard"}}}) == \
        "preprocess.brackets.method: must be one of mertens, debevec; got 'reinhard'"
    assert config_error({"images": "a", "video": "b.mp4"}).startswith("video: the input is either")


def test_defaults_written_out_or_not_give_one_config():
    short = load_config({"preprocess": {"ops": [{"op": "clahe", "clip_limit": 3}]}}).stages["preprocess"]
    full = load_config({"preprocess": {"ops": [{"op": "clahe", "clip_limit": 3.0, "tiles": 8}]}}).stages["preprocess"]
    assert short == full
    assert short.ops == [{"op": "clahe", "clip_limit": 3.0, "tiles": 8}]
    (name, options), = short.steps()
    assert name == "clahe" and options.clip_limit == 3.0


def test_no_ops_links_ingest_images(small_scene, tmp_path):
    ws = tmp_path / "ws"
    recon.run({"until": "preprocess"}, images=str(small_scene / "images"), workspace=str(ws))
    out, ingest = output(ws, "preprocess"), output(ws, "ingest")
    for folder in ("images", "images_geometric"):
        assert (out / folder).is_symlink() and (out / folder).resolve() == (ingest / "images").resolve()
    listing, source = read_json(out / "images.json"), read_json(ingest / "images.json")
    assert [i["name"] for i in listing["images"]] == [i["name"] for i in source["images"]]
    cam, src = listing["cameras"][0], source["cameras"][0]
    assert (cam["model"], cam["width"], cam["height"]) == (src["model"], 320, 240)
    assert cam["params"] == [src["focal"], 160.0, 120.0, 0.0] and not cam["fixed"]
    assert (ws / "images").resolve() == (ingest / "images").resolve()  # the workspace's images: the originals


def test_photometric_ops_reach_features_only(small_scene, tmp_path):
    """A photometric chain changes images/ and leaves images_geometric/ (what dense reads) the originals."""
    ws = tmp_path / "ws"
    ops = [{"op": "bilateral"}, {"op": "clahe", "clip_limit": 3.0}]
    recon.run({"until": "preprocess", "preprocess": {"ops": ops}}, images=str(small_scene / "images"),
              workspace=str(ws))
    out = output(ws, "preprocess")
    names = sorted(p.name for p in (small_scene / "images").iterdir())
    changed = []
    for name in names:
        original = pixels(small_scene / "images" / name)
        assert np.array_equal(pixels(out / "images_geometric" / name), original)
        processed = pixels(out / "images" / name)
        assert processed.shape == original.shape
        changed.append(np.abs(processed.astype(int) - original).mean())
    print(f"mean abs change by bilateral + CLAHE: {np.mean(changed):.1f} grey levels")
    assert min(changed) > 2.0
    assert read_json(out / "images.json")["cameras"][0]["width"] == 320


def test_changing_an_op_option_reruns_preprocess_and_what_follows(small_scene, tmp_path):
    ws = tmp_path / "ws"
    config = {"until": "features", "preprocess": {"ops": [{"op": "clahe", "clip_limit": 2.0}]}}
    first = recon.run(config, images=str(small_scene / "images"), workspace=str(ws))
    assert first.ran == ["ingest", "calibrate", "preprocess", "features"]
    change = ["preprocess.ops=[{op: clahe, clip_limit: 4.0}]"]
    rows = {r.name: r for r in recon.api.status(config, change, images=str(small_scene / "images"),
                                                 workspace=str(ws))}
    assert rows["ingest"].state == "done" and rows["calibrate"].state == "done"
    assert rows["preprocess"].state == "stale" and "preprocess.ops" in rows["preprocess"].why
    assert rows["features"].state == "stale" and rows["features"].why == "upstream changed: preprocess"
    again = recon.run(config, images=str(small_scene / "images"), workspace=str(ws), overrides=change)
    assert again.ran == ["preprocess", "features"] and again.cached == ["ingest", "calibrate"]


def test_resize_scales_cameras_and_masks(small_scene, tmp_path):
    """Resize by 0.5 with a mask hiding the left half: sizes, intrinsics, masks and keypoints follow."""
    masks = tmp_path / "masks"
    masks.mkdir()
    names = sorted(p.name for p in (small_scene / "images").iterdir())
    hidden = np.full((240, 320), 255, np.uint8)
    hidden[:, :160] = 0
    for name in names[:4]:  # the others have no mask: all of them is used
        Image.fromarray(hidden).save(masks / f"{name}.png")
    ws = tmp_path / "ws"
    recon.run({"until": "features", "preprocess": {"ops": [{"op": "resize", "scale": 0.5}], "mask_dir": str(masks)},
               "features": {"masks": True}},
              images=str(small_scene / "images"), workspace=str(ws))
    out = output(ws, "preprocess")
    listing = read_json(out / "images.json")
    source = read_json(output(ws, "ingest") / "images.json")["cameras"][0]
    cam = listing["cameras"][0]
    assert (cam["width"], cam["height"]) == (160, 120)
    assert cam["params"] == pytest.approx([source["focal"] / 2, 80.0, 60.0, 0.0])
    for name in names:
        assert pixels(out / "images" / name).shape == (120, 160, 3)
        assert pixels(out / "images_geometric" / name).shape == (120, 160, 3)
    assert [i["masked"] for i in listing["images"]] == [True] * 4 + [False] * (len(names) - 4)
    mask = pixels(out / "masks" / f"{names[0]}.png")
    assert mask.shape == (120, 160) and not mask[:, :80].any() and mask[:, 80:].all()
    features = output(ws, "features") / "features"
    masked_x = load_features(features / f"{names[0]}.npz")[0][:, 0]
    free_x = load_features(features / f"{names[5]}.npz")[0][:, 0]
    print(f"keypoints: masked image {len(masked_x)} (min x {masked_x.min():.1f}), unmasked {len(free_x)}")
    assert len(masked_x) > 50 and masked_x.min() >= 80.0
    assert (free_x < 80).sum() > 50
    assert (ws / "masks").resolve() == (out / "masks").resolve()


def test_mask_of_another_size_is_an_error(small_scene, tmp_path):
    masks = tmp_path / "masks"
    masks.mkdir()
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(masks / "view_000.jpg.png")
    with pytest.raises(StageError, match="preprocess.mask_dir: mask .* is 10x10, its image 320x240"):
        recon.run({"until": "preprocess", "executor": "serial", "preprocess": {"mask_dir": str(masks)}},
                  images=str(small_scene / "images"), workspace=str(tmp_path / "ws"))


def test_undistort_without_calibration_is_refused(small_scene, tmp_path):
    with pytest.raises(StageError, match="'undistort' needs the photos' distortion"):
        recon.run({"until": "preprocess", "preprocess": {"ops": [{"op": "undistort"}]}},
                  images=str(small_scene / "images"), workspace=str(tmp_path / "ws"))


def test_an_interrupted_preprocess_resumes_with_the_views_left(small_scene, tmp_path, caplog, monkeypatch):
    """A run killed at its last view keeps the others; the next run processes that view only."""
    names = sorted(p.name for p in (small_scene / "images").iterdir())
    process = preprocess_stage._process_view

    def killed_at_last(task):
        if task.view.name == names[-1]:
            raise KeyboardInterrupt
        process(task)

    config = {"until": "preprocess", "executor": "serial", "preprocess": {"ops": [{"op": "clahe"}]}}
    ws = tmp_path / "ws"
    monkeypatch.setattr(preprocess_stage, "_process_view", killed_at_last)
    with pytest.raises(KeyboardInterrupt):
        recon.run(config, images=str(small_scene / "images"), workspace=str(ws))
    partial = next((ws / ".recon" / "cache" / "preprocess").glob("*.partial"))
    done = {p.name: p.stat().st_mtime_ns for p in (partial / "images").iterdir()}
    assert sorted(done) == names[:-1]
    monkeypatch.setattr(preprocess_stage, "_process_view", process)
    with caplog.at_level("INFO", logger="recon"):
        recon.run(config, images=str(small_scene / "images"), workspace=str(ws))
    assert f"preprocess: {len(names) - 1} of {len(names)} already done, resuming" in caplog.text
    out = output(ws, "preprocess")
    assert all((out / "images" / name).stat().st_mtime_ns == t for name, t in done.items())
    assert sorted(p.name for p in (out / "images").iterdir()) == names and not (out / "items").exists()
