"""features: SIFT keypoints and descriptors of every photo (COLMAP's SIFT, via pycolmap), into database.db.

Reads preprocess's images (every 2D operation applied) and cameras (intrinsics of those pixels; a
calibration's parameters as given); keypoints where preprocess's mask is zero are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from recon.config import ConfigError
from recon.imaging.masks import inside_mask, load_mask
from recon.logs import quiet_colmap
from recon.options import opt
from recon.sparse.database import opened, write_database
from recon.sparse.features import ONNX_ONLY, SiftSettings, extract_sift, load_features, save_features
from recon.stage import Stage, StageContext, register
from recon.workspace import read_json, write_json


@dataclass(frozen=True)
class FeaturesConfig:
    type: str = opt("sift", "feature type; only 'sift' runs on the CPU pycolmap wheel")
    max_image_size: int = opt(1600, "longest image side for extraction (photos are downsized, anti-aliased)", gt=0)
    max_num_features: int = opt(8192, "keep at most this many features per photo", gt=0)
    min_image_size: int = opt(800, "smaller photos are upsized (bicubic) to this longest side for extraction",
                              ge=0)
    first_octave: int = opt(0, "SIFT first octave: -1 upsamples 2x inside SIFT (COLMAP's default; slow)",
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
        return SiftSettings(self.max_image_size, self.min_image_size, self.max_num_features, self.first_octave,
                            self.peak_threshold,
                            self.edge_threshold, self.estimate_affine_shape, self.domain_size_pooling,
                            self.upright, self.darkness_adaptivity)


def extract_one(task: tuple[Path, Path, SiftSettings, Path | None]) -> int:
    """One photo's SIFT (source, destination .npz, settings, mask folder or None), in a worker; its count."""
    source, dest, settings, mask_dir = task
    quiet_colmap()  # a worker process: COLMAP's info lines would flood the terminal
    keypoints, descriptors = extract_sift(source, settings)
    mask = load_mask(mask_dir, dest.name.removesuffix(".npz")) if mask_dir is not None else None
    if mask is not None:
        keep = inside_mask(mask, keypoints[:, :2])
        keypoints, descriptors = keypoints[keep], descriptors[keep]
    save_features(dest, keypoints, descriptors)
    return len(keypoints)


@register
class Features(Stage):
    name = "features"
    version = 1
    Config = FeaturesConfig
    requires = ("preprocess",)
    outputs = ("features/<image>.npz", "database.db", "images.json")
    publish = {"database.db": "database.db"}
    summary = "SIFT features per photo, written into COLMAP's database.db"

    def run(self, ctx: StageContext, cfg: FeaturesConfig) -> dict:
        preprocess = ctx.input("preprocess")
        listing = read_json(preprocess / "images.json")
        settings = cfg.settings()
        masks = preprocess / "masks"
        tasks = [(preprocess / "images" / img["name"], ctx.out / "features" / f"{img['name']}.npz", settings,
                  (masks / img["name"]).parent if img.get("masked") else None) for img in listing["images"]]
        ctx.map(extract_one, tasks, desc="features", done=lambda t: t[1].is_file())
        counts = []

        def features():
            for img, (_, npz, _, _) in zip(listing["images"], tasks):
                keypoints, descriptors = load_features(npz)
                counts.append(len(keypoints))
                yield img["name"], keypoints, descriptors

        write_database(ctx.out / "database.db", listing["cameras"], listing["images"], features())
        _set_camera_params(ctx.out / "database.db", listing)
        write_json(ctx.out / "images.json", listing)  # what the database holds, for matching (``ordered``)
        return {"images": len(counts), "median_features": int(sorted(counts)[len(counts) // 2]),
                "min_features": int(min(counts))}


def _set_camera_params(database: Path, listing: dict) -> None:
    """Give the database's cameras preprocess's parameters (principal point, distortion of a calibration).

    Cameras of a calibration used as ``fixed`` or a prior are marked as having a known focal length,
    so COLMAP neither re-estimates nor refines it when it registers their first image.
    """
    import pycolmap

    cameras = {c["id"]: c for c in listing["cameras"]}
    by_name = {img["name"]: img["camera"] for img in listing["images"]}
    with opened(database) as db:
        done = set()
        for image in db.read_all_images():
            if image.camera_id in done:
                continue
            done.add(image.camera_id)
            cam = cameras[by_name[image.name]]
            camera = pycolmap.Camera(model=cam["model"], width=cam["width"], height=cam["height"],
                                     params=cam["params"], camera_id=image.camera_id)
            camera.has_prior_focal_length = bool(cam["prior_focal"])
            db.update_camera(camera)
