"""The ready configs of issue 5: pipelines/video.yaml and pipelines/lowlight.yaml."""

from __future__ import annotations

from pathlib import Path

from recon.imaging.ops import LOW_LIGHT
from recon.pipeline import load_config, selected_stages

PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"


def test_lowlight_config_is_the_library_low_light_chain():
    cfg = load_config(PIPELINES / "lowlight.yaml")
    assert cfg.stages["preprocess"].steps() == list(LOW_LIGHT)
    assert selected_stages(cfg)[-2:] == ["export", "report"]


def test_video_config_matches_frames_in_sequence():
    cfg = load_config(PIPELINES / "video.yaml", ["video=clip.mp4"])
    assert cfg.video == (PIPELINES / "clip.mp4").resolve() and cfg.images is None
    assert cfg.stages["matching"].method == "sequential"
    assert cfg.stages["ingest"].keyframes.min_parallax == 0.05
    assert selected_stages(cfg) == ["ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export",
                                    "report"]
