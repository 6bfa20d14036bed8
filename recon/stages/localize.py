"""localize: place new photos in an existing reconstruction (COLMAP's image registrator, hloc).

The new photos are the run's ``images:`` (through ingest); ``localize.model`` names the reference:
the folder of a finished reconstruction, holding ``sparse/0`` and ``database.db`` (a recon
workspace, or a COLMAP project laid out that way). The photos' SIFT features are extracted with the
settings the reference's features were (read from its features stage manifest), then each photo is
placed by :mod:`recon.localize`. Outputs: ``poses.json`` (per photo: placed or the reason not,
pose, intrinsics, matches, inliers) and ``sparse/0``: the reference model with the placed photos
added and nothing of it changed. A changed reference model or database changes the cache key.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from recon.config import ConfigError, build
from recon.files import read_json, write_json
from recon.localize import (
    LocalizeOptions,
    Photo,
    PhotoCamera,
    add_placed,
    load_reference,
    localize,
    poses_json,
)
from recon.options import opt
from recon.products import Localization, Photos, Published
from recon.sparse.features import FeaturesConfig, SiftSettings, extract_photo, load_features
from recon.stage import Progress, Stage, StageContext, StageError, register
from recon.workspace import Workspace


@dataclass(frozen=True)
class LocalizeConfig(LocalizeOptions):
    model: str | None = opt(None, "the reference: folder of a finished reconstruction with sparse/0 and "
                                  "database.db (a recon workspace); relative to the config file")


@dataclass(frozen=True)
class _Reference:
    root: Path
    model: Path
    database: Path


def _reference(ctx: StageContext, cfg: LocalizeConfig) -> _Reference:
    if not cfg.model:
        raise StageError("localize.model: no reference given; set it to the workspace of a finished "
                         "reconstruction (e.g. one made by `recon run pipelines/sparse.yaml`)")
    root = ctx.resolve(cfg.model)
    published = Published(root)
    ref = _Reference(root, published.model(), published.database)
    missing = [p.relative_to(root).as_posix() for p in (ref.model / "images.bin", ref.database) if not p.is_file()]
    if missing:
        raise StageError(f"localize.model: {root} has no {' or '.join(missing)}; give the folder of a finished "
                         "reconstruction (with sparse/0 and database.db)")
    return ref


def _sift_settings(ctx: StageContext, ref: _Reference) -> SiftSettings:
    """The SIFT settings of the reference's features: from the manifest of the features output its
    database was made from (recon workspaces), else recon's defaults."""
    ws = Workspace(ref.root)
    made_by = read_json(ref.database.resolve().parent / "manifest.json") or {}
    key = made_by.get("key") if made_by.get("stage") == "features" else made_by.get("upstream", {}).get("features")
    manifest = ws.manifest("features", key) if key else None
    if manifest is None:
        ctx.log.warning("localize: %s records no features settings (not a recon workspace?); extracting SIFT "
                        "with recon's defaults", ref.root)
        return FeaturesConfig().settings()
    try:
        return build(FeaturesConfig, manifest["config"], "features").settings()
    except ConfigError as exc:
        ctx.log.warning("localize: the reference's features settings do not apply (%s); using recon's defaults",
                        exc)
        return FeaturesConfig().settings()


def _photo_camera(image: dict, cameras: dict[int, dict]) -> PhotoCamera:
    """Ingest's record of a photo as a camera: its own EXIF focal, else its camera group's focal."""
    group = cameras[image["camera"]]
    focal = image.get("focal_px") or group["focal"]
    return PhotoCamera(image["width"], image["height"], float(focal), bool(image.get("focal_px") or group["prior_focal"]),
                       group["model"])


@register
class Localize(Stage):
    name = "localize"
    version = 1
    Config = LocalizeConfig
    requires = (Photos,)
    produces = Localization
    uses_seed = True
    summary = "place new photos in an existing reconstruction: retrieval, 2D-3D matches, absolute pose"

    def fingerprint(self, ctx: StageContext, cfg: LocalizeConfig):
        ref = _reference(ctx, cfg)
        files = [*sorted(ref.model.glob("*.bin")), ref.database]
        return [[f.relative_to(ref.root).as_posix(), ctx.digest(f)] for f in files]

    def run(self, ctx: StageContext, cfg: LocalizeConfig) -> dict:
        ref = _reference(ctx, cfg)
        settings = _sift_settings(ctx, ref)
        photos = ctx.input(Photos)
        listing = photos.listing()
        images = listing["images"]
        tasks = [(photos.images / img["name"], ctx.output.features(img["name"]), settings, None) for img in images]
        ctx.map(extract_photo, tasks, desc="features", done=lambda t: t[1].is_file())
        cameras = {c["id"]: c for c in listing["cameras"]}
        photos = [Photo(img["name"], _photo_camera(img, cameras), *load_features(npz))
                  for img, (_, npz, _, _) in zip(images, tasks)]
        try:
            reference = load_reference(ref.model, ref.database)
        except ValueError as exc:
            raise StageError(f"localize.model: {exc}") from None
        progress = Progress(ctx.log, "localize", len(photos))

        def done(placement) -> None:
            if placement.placed:
                ctx.log.debug("placed %s: %d inliers of %d matches", placement.name, placement.inliers,
                              placement.matches)
            else:
                ctx.log.warning("not placed: %s: %s", placement.name, placement.reason)
            progress.advance()

        try:
            placements = localize(reference, photos, cfg, ctx.seed, done)  # cfg is-a LocalizeOptions
        finally:
            progress.close()
        rec = reference.reconstruction
        added = add_placed(rec, placements, {p.name: p for p in photos})
        model = ctx.output.model()
        model.mkdir(parents=True, exist_ok=True)
        rec.write(str(model))
        write_json(ctx.output.poses, {"reference": str(ref.root), **poses_json(placements, added)})
        placed = [p for p in placements if p.placed]
        if not placed:
            ctx.log.warning("localize: no photo could be placed in %s", ref.root)
        inliers = sorted(p.inliers for p in placed)
        return {"photos": len(photos), "placed": len(placed), "reference_images": len(reference.image_ids),
                "median_inliers": inliers[len(inliers) // 2] if inliers else 0,
                "model_images": rec.num_reg_images(), "sift": asdict(settings)}
