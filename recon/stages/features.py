"""features: SIFT keypoints and descriptors of every photo (COLMAP's SIFT, via pycolmap), into database.db."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from recon.config import ConfigError
from recon.logs import quiet_colmap
from recon.options import opt
from recon.sparse.database import write_database
from recon.sparse.features import ONNX_ONLY, SiftSettings, extract_sift, load_features, save_features
from recon.stage import Stage, StageContext, register
from recon.workspace import read_json


@dataclass(frozen=True)
class FeaturesConfig:
    type: str = opt("sift", "feature type; only 'sift' runs on the CPU pycolmap wheel")
    max_image_size: int = opt(1600, "longest image side for extraction (photos are downsized, anti-aliased)", gt=0)
    max_num_features: int = opt(8192, "keep at most this many features per photo", gt=0)
    first_octave: int | None = opt(None, "SIFT first octave: -1 upsamples 2x; null = -1 below 1200 px, else 0",
                                   ge=-1, le=3)
    peak_threshold: float = opt(0.0066667, "SIFT peak (contrast) threshold; lower = more features in "
                                           "low-contrast photos", gt=0)
    edge_threshold: float = opt(10.0, "SIFT edge threshold", gt=0)
    estimate_affine_shape: bool = opt(False, "estimate affine keypoint shape (slower, helps wide baselines)")
    domain_size_pooling: bool = opt(False, "DSP-SIFT descriptors (slower, more robust)")
    upright: bool = opt(False, "skip orientation estimation (photos all upright)")
    darkness_adaptivity: bool = opt(False, "adapt the threshold in dark images")

    def __post_init__(self):
        if self.type.lower() in ONNX_ONLY:
            raise ConfigError(
                f"features.type: '{self.type}' needs pycolmap built with ONNX support; on the CPU wheel "
                "it aborts the whole process (uncatchable), so recon refuses it. Use 'sift'.")
        if self.type.lower() != "sift":
            raise ConfigError(f"features.type: unknown feature type '{self.type}'; use 'sift'")

    def settings(self) -> SiftSettings:
        return SiftSettings(self.max_image_size, self.max_num_features, self.first_octave, self.peak_threshold,
                            self.edge_threshold, self.estimate_affine_shape, self.domain_size_pooling,
                            self.upright, self.darkness_adaptivity)


def _extract_one(task: tuple[Path, Path, SiftSettings]) -> int:
    source, dest, settings = task
    quiet_colmap()  # a worker process: COLMAP's info lines would flood the terminal
    keypoints, descriptors = extract_sift(source, settings)
    save_features(dest, keypoints, descriptors)
    return len(keypoints)


@register
class Features(Stage):
    name = "features"
    version = 1
    Config = FeaturesConfig
    requires = ("ingest",)
    outputs = ("features/<image>.npz", "database.db")
    publish = {"database.db": "database.db"}
    summary = "SIFT features per photo, written into COLMAP's database.db"

    def run(self, ctx: StageContext, cfg: FeaturesConfig) -> dict:
        ingest = ctx.input("ingest")
        listing = read_json(ingest / "images.json")
        settings = cfg.settings()
        tasks = [(ingest / "images" / img["name"], ctx.out / "features" / f"{img['name']}.npz", settings)
                 for img in listing["images"]]
        ctx.map(_extract_one, tasks, desc="features", done=lambda t: t[1].is_file())
        counts = []

        def features():
            for img, (_, npz, _) in zip(listing["images"], tasks):
                keypoints, descriptors = load_features(npz)
                counts.append(len(keypoints))
                yield img["name"], keypoints, descriptors

        write_database(ctx.out / "database.db", listing["cameras"], listing["images"], features())
        return {"images": len(counts), "median_features": int(sorted(counts)[len(counts) // 2]),
                "min_features": int(min(counts))}
