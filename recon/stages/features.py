"""features: SIFT keypoints and descriptors of every photo (COLMAP's SIFT, via pycolmap), into database.db.

Reads preprocess's images (every 2D operation applied) and cameras (intrinsics of those pixels; a
calibration's parameters as given); keypoints where preprocess's mask is zero are dropped.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from recon.imaging.masks import mask_path
from recon.items import ItemStore, item_key
from recon.products import FeatureDatabase, PreparedPhotos
from recon.sparse.database import opened, write_database
from recon.sparse.features import FeaturesConfig, extract_photo, load_features
from recon.sparse.fisheye_focal import estimate_focal
from recon.sparse.lens import FISHEYE_MODELS
from recon.stage import Stage, StageContext, register


@register
class Features(Stage):
    name = "features"
    version = 2
    Config = FeaturesConfig
    requires = (PreparedPhotos,)
    produces = FeatureDatabase
    summary = "SIFT features per photo, written into COLMAP's database.db"

    def run(self, ctx: StageContext, cfg: FeaturesConfig) -> dict:
        photos = ctx.input(PreparedPhotos)
        listing = photos.listing()
        settings = cfg.settings()
        out = ctx.output
        tasks = [(photos.images / img["name"], out.features(img["name"]), settings,
                  (photos.masks / img["name"]).parent if cfg.masks and img.get("masked") else None)
                 for img in listing["images"]]
        store = ItemStore(ctx.workspace.items_dir(self.name), ".npz")
        named_keys = self.item_keys(ctx, cfg, photos, listing)
        out.write_item_keys(named_keys)
        keys = [*named_keys.values()]
        reused = {i for i, (key, t) in enumerate(zip(keys, tasks))
                  if ctx.reuse and not t[1].is_file() and store.link(key, t[1])}
        if reused:
            ctx.log.info("features: %d of %d photos' features reused from earlier runs", len(reused), len(tasks))
        ctx.map(extract_photo, [t for i, t in enumerate(tasks) if i not in reused], desc="features",
                done=lambda t: t[1].is_file())
        for i, (key, (_, npz, _, _)) in enumerate(zip(keys, tasks)):
            if i not in reused:
                store.put(key, npz)
        counts = []

        def features():
            for img, (_, npz, _, _) in zip(listing["images"], tasks):
                keypoints, descriptors = load_features(npz)
                counts.append(len(keypoints))
                yield img["name"], keypoints, descriptors

        focals = _fisheye_focals(ctx, listing, {img["name"]: t[1] for img, t in zip(listing["images"], tasks)},
                                 cfg.max_image_size)
        write_database(out.database, listing["cameras"], listing["images"], features())
        _set_camera_params(out.database, listing)
        out.write_listing(listing)  # what the database holds, for matching (``ordered``)
        return {"images": len(counts), "median_features": int(sorted(counts)[len(counts) // 2]),
                "min_features": int(min(counts)), "reused": len(reused), "extracted": len(tasks) - len(reused),
                **({"fisheye_focal": focals} if focals else {})}

    def reusable(self, ctx: StageContext, cfg: FeaturesConfig) -> str:
        photos = ctx.input(PreparedPhotos)
        keys = self.item_keys(ctx, cfg, photos, photos.listing())
        store = ItemStore(ctx.workspace.items_dir(self.name), ".npz")
        return f"reuses the features of {sum(store.get(k) is not None for k in keys.values())} of {len(keys)} photos"

    def item_keys(self, ctx: StageContext, cfg: FeaturesConfig, photos: PreparedPhotos,
                  listing: dict) -> dict[str, str]:
        """Per photo (by name, in the listing's order), the key of its features in the item store
        (:mod:`recon.items`): the prepared image's content, its mask's where keypoints are masked,
        and the extraction settings; nothing about the other photos."""
        settings = dataclasses.asdict(cfg.settings())
        keys = {}
        for img in listing["images"]:
            mask = mask_path(photos.masks, img["name"]) if cfg.masks and img.get("masked") else None
            keys[img["name"]] = item_key({
                "item": "sift", "version": self.version, "settings": settings,
                "image": ctx.digest(photos.images / img["name"]),
                "mask": ctx.digest(mask) if mask is not None and mask.is_file() else None})
        return keys


def _fisheye_focals(ctx: StageContext, listing: dict, npz: dict[str, Path], max_image_size: int) -> dict[int, float]:
    """Estimate the focal length of each fisheye camera that has no prior (recon.sparse.fisheye_focal):
    COLMAP registers nothing without one. The estimate becomes the camera's prior, in ``listing``;
    returns camera id -> focal."""
    import pycolmap

    found = {}
    for cam in listing["cameras"]:
        if cam["model"] not in FISHEYE_MODELS or cam["prior_focal"]:
            continue
        names = sorted(img["name"] for img in listing["images"] if img["camera"] == cam["id"])
        camera = pycolmap.Camera(model=cam["model"], width=cam["width"], height=cam["height"], params=cam["params"])
        threshold = 0.5 * max(1.0, max(cam["width"], cam["height"]) / max_image_size)  # ~0.5 px where SIFT ran
        estimate = estimate_focal(camera, len(names), lambda i, names=names: load_features(npz[names[i]]), threshold)
        if estimate is None:
            ctx.log.warning("features: camera %d (%s): no two photos taken one after the other share enough "
                            "matches to estimate the fisheye focal length; give it in ingest (EXIF) or a "
                            "calibration", cam["id"], cam["model"])
            continue
        for i in camera.focal_length_idxs():
            cam["params"][i] = estimate.focal
        cam["focal"], cam["prior_focal"] = estimate.focal, True
        ctx.log.info("features: camera %d: fisheye focal length %.1f px (%.0f degrees across the diagonal), "
                     "estimated on %d pairs", cam["id"], estimate.focal, estimate.diagonal_fov_deg, estimate.pairs)
        found[cam["id"]] = round(estimate.focal, 2)
    return found


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
