"""The colmap-cuda backend: the configured options reach COLMAP's PatchMatch, and the backend that
made the depth maps is part of the mvs cache key. Runs without a GPU: pycolmap's function is patched."""

from __future__ import annotations

from pathlib import Path

import pycolmap

import recon.stages.mvs as mvs_stage
from recon.pipeline import load_config, plan
from recon.products import DenseScene
from recon.stage import StageContext
from recon.workspace import HashCache, Workspace


def test_the_cuda_adapter_receives_the_configured_options(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(pycolmap, "patch_match_stereo",
                        lambda workspace, options=None, **kw: seen.update(workspace=workspace, options=options))
    monkeypatch.setattr(mvs_stage, "cuda_available", lambda: True)
    dense = DenseScene(tmp_path / "undistort")
    dense.images.mkdir(parents=True)
    dense.model.mkdir()
    out = tmp_path / "mvs"
    out.mkdir()
    ws = Workspace(tmp_path / "ws")
    ctx = StageContext(name="mvs", out=out, workspace=ws, images=None, seed=0, executor=None, base=tmp_path,
                       hashes=HashCache(ws), upstream={"undistort": dense.root})
    cfg = mvs_stage.MvsConfig(backend="colmap-cuda", max_image_size=800, window_radius=7, geometric=False,
                              filter_min_consistent=3)
    summary = mvs_stage.Mvs().run(ctx, cfg)
    assert summary["backend"] == "colmap-cuda"
    options = seen["options"]
    assert (options.max_image_size, options.window_radius, options.geom_consistency,
            options.filter_min_num_consistent) == (800, 7, False, 3)
    workspace = Path(seen["workspace"])
    assert (workspace / "images").resolve() == dense.images and (workspace / "sparse").resolve() == dense.model
    assert (workspace / "stereo").resolve() == out / "stereo"


def test_the_backend_is_part_of_the_mvs_key(small_scene, tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws")
    ws.create()

    def key(backend: str, cuda: bool) -> str:
        monkeypatch.setattr(mvs_stage, "cuda_available", lambda: cuda)
        cfg = load_config({"images": str(small_scene / "scene" / "images"), "workspace": str(ws.root), "until": "mvs",
                           "mvs": {"backend": backend}})
        return plan(cfg, ws).keys["mvs"]

    assert key("cpu", False) != key("colmap-cuda", True)
    assert key("auto", False) != key("auto", True)  # `auto` is resolved before the key is made
    assert key("cpu", False) == key("cpu", True)
