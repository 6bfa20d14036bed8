"""ingest: a folder of photos (or a video's keyframes) -> a checked image list with camera groups and
EXIF focal priors.

A video (``video:`` instead of ``images:``) becomes keyframes (:mod:`recon.imaging.video`: sharp
frames spread by optical-flow parallax) written into ``images/``; the list is then marked
``"ordered": true`` so matching pairs the frames sequentially.
"""

from __future__ import annotations

import dataclasses
import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from recon.imaging.video import KeyframeOptions, extract_keyframes
from recon.options import opt
from recon.products import Photos
from recon.sparse import lens
from recon.sparse.photos import Listing, PhotoError, inspect_photo, list_photos, normalized_copy
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class IngestConfig:
    camera_mode: Literal["auto", "single", "per_folder", "per_image"] = opt(
        "auto", "camera grouping: auto = one per folder, per image where sizes differ in a folder")
    camera_model: Literal["auto", "SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV",
                          "SIMPLE_FISHEYE", "FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE",
                          "EQUIRECTANGULAR"] = opt(
        "auto", "COLMAP camera model fitted by bundle adjustment; auto: by the photos' metadata "
                         "(fisheye lens: OPENCV_FISHEYE, 360 panorama: EQUIRECTANGULAR, else SIMPLE_RADIAL)")
    default_focal_factor: float = opt(1.2, "focal = factor x max(width, height) when EXIF has none", gt=0)
    min_photos: int = opt(2, "fewest readable photos the run needs (2 to reconstruct; localize takes 1)", ge=1)
    skip_unreadable: bool = opt(True, "skip corrupt/empty photos with a warning instead of stopping")
    keyframes: KeyframeOptions = opt(KeyframeOptions(), "video input: how keyframes are chosen")


def _video(ctx: StageContext) -> Path | None:
    video = ctx.video
    if video is not None and not Path(video).is_file():
        raise StageError(f"video: {video} is not a file; give the path of the video to take frames from")
    return video


def _images_folder(ctx: StageContext):
    if ctx.images is None:
        raise StageError("images: no photo folder given; set `images:` (or `video:`) in the config or pass "
                         "--images DIR")
    if not ctx.images.is_dir():
        raise StageError(f"images: {ctx.images} is not a folder; pass the folder that holds the photos")
    return ctx.images


def _listing(ctx: StageContext, folder: Path) -> Listing:
    """The photo folder's listing without the workspace's own files: when the workspace is the photo
    folder, the links recon published there; when it lies inside it, the whole workspace."""
    ws, real = ctx.workspace, Path(os.path.realpath(ctx.workspace.root))
    inside = real != folder and real.is_relative_to(folder)
    return list_photos(folder, exclude=lambda p: ws.owns(p) or (inside and p.is_relative_to(real)))


def _fingerprint(ctx: StageContext, folder: Path) -> list[list[str]]:
    """(name, content hash) of each photo; one that cannot be read is left out (ingest skips it too)."""
    rows = []
    for path in _listing(ctx, folder).photos:
        try:
            rows.append([path.relative_to(folder).as_posix(), ctx.digest(path)])
        except OSError:
            continue
    return rows


@register
class Ingest(Stage):
    name = "ingest"
    version = 2
    Config = IngestConfig
    produces = Photos
    summary = "check the photos, group them into cameras, read EXIF focal lengths and GPS positions"

    def fingerprint(self, ctx: StageContext, cfg: IngestConfig):
        video = _video(ctx)
        if video is not None:
            return [[video.name, ctx.digest(video)]]
        return _fingerprint(ctx, _images_folder(ctx))

    def run(self, ctx: StageContext, cfg: IngestConfig) -> dict:
        video = _video(ctx)
        if video is not None:
            folder = ctx.output.images
            extract_keyframes(video, folder, cfg.keyframes)
        else:
            folder = _images_folder(ctx)
        listing = _listing(ctx, folder) if video is None else list_photos(folder)  # keyframes: recon's own
        photos, others = listing.photos, listing.others
        for path, why in listing.unreadable:
            ctx.log.warning("skipped: %s: %s", path, why)
        if others:
            shown = ", ".join(p.name for p in others[:5]) + (" ..." if len(others) > 5 else "")
            ctx.log.warning("skipped %d files that are not JPEG/PNG/TIFF photos: %s", len(others), shown)
        if not photos:
            raise StageError(f"images: {folder} holds no JPEG, PNG or TIFF photos")
        infos, bad = [], [f"{path}: {why}" for path, why in listing.unreadable]
        for path in photos:
            try:
                infos.append((path, inspect_photo(path, path.relative_to(folder).as_posix())))
            except PhotoError as exc:
                if not cfg.skip_unreadable:
                    raise StageError(str(exc)) from None
                ctx.log.warning("skipped: %s", exc)
                bad.append(str(exc))
        if len(infos) < cfg.min_photos:
            if video is not None:
                raise StageError(f"video: {video.name} gave {len(infos)} keyframe(s); the run needs at least "
                                 f"{cfg.min_photos}: lower ingest.keyframes.min_parallax, or film more motion")
            raise StageError(f"images: {folder} has {len(infos)} readable photo(s); the run needs at least "
                             f"{cfg.min_photos} (ingest.min_photos)")
        copies = _place_photos(ctx.output.images, infos) if video is None else 0  # keyframes are there
        cameras, image_camera = _group_cameras([i for _, i in infos], cfg)
        for cam in cameras:
            members = [i for _, i in infos if image_camera[i.name] == cam["id"]]
            why = lens.model_warning(cam["model"], [i.projection for i in members],
                                     [(i.width, i.height) for i in members])
            if why:
                ctx.log.warning("ingest: camera %d (%s%s): %s", cam["id"], members[0].name,
                                ", ..." if len(members) > 1 else "", why)
        duplicates = _duplicates(ctx, [(p, i.name) for p, i in infos])
        for group in duplicates:
            ctx.log.warning("identical photos (kept, but they add nothing): %s", ", ".join(group))
        ctx.output.write_listing({
            "images": [{"name": i.name, "width": i.width, "height": i.height, "camera": image_camera[i.name],
                        "focal_px": i.focal_px, "converted": i.needs_copy, "projection": i.projection,
                        "gps": dataclasses.asdict(i.gps) if i.gps else None} for _, i in infos],
            "cameras": cameras,
            "skipped": [str(p) for p in others] + bad,
            "duplicates": duplicates,
            "ordered": video is not None,
        })
        with_exif = sum(1 for _, i in infos if i.focal_px)
        return {"images": len(infos), "cameras": len(cameras), "exif_focal": with_exif,
                "gps": sum(1 for _, i in infos if i.gps),
                "converted": copies, "skipped": len(others) + len(bad), "duplicates": len(duplicates),
                "ordered": video is not None}


def _place_photos(out_images: Path, infos) -> int:
    """Link each photo into ``out_images``, or write its upright 8-bit copy; returns the copies made."""
    out_images.mkdir(exist_ok=True)
    copies = 0
    for path, info in infos:
        dest = out_images / info.name
        if info.needs_copy:
            if not dest.exists() or dest.is_symlink():
                normalized_copy(path, dest)
            copies += 1
        else:
            dest.parent.mkdir(parents=True, exist_ok=True)
            if dest.is_symlink() or dest.exists():
                dest.unlink()
            os.symlink(path.resolve(), dest)
    return copies


def _group_cameras(infos, cfg: IngestConfig) -> tuple[list[dict], dict[str, int]]:
    """Camera groups: one per folder (auto), splitting a folder per image when photo sizes differ."""
    groups: dict[tuple, list] = defaultdict(list)
    for info in infos:
        folder = info.name.rsplit("/", 1)[0] if "/" in info.name else ""
        if cfg.camera_mode == "single":
            key = ("", info.width, info.height)
        elif cfg.camera_mode == "per_image":
            key = (info.name,)
        else:
            key = (folder,)
        groups[key].append(info)
    if cfg.camera_mode in ("auto", "single"):
        split: dict[tuple, list] = {}
        for key, members in groups.items():
            if len({(i.width, i.height) for i in members}) > 1:
                if cfg.camera_mode == "single":
                    raise StageError("ingest.camera_mode: 'single' but the photos have different sizes; "
                                     "use 'auto' or 'per_image'")
                split.update({(i.name,): [i] for i in members})
            else:
                split[key] = members
        groups = split
    cameras, image_camera = [], {}
    for cam_id, members in enumerate(groups.values(), start=1):
        first = members[0]
        focals = [i.focal_px for i in members if i.focal_px]
        prior = bool(focals)
        focal = sorted(focals)[len(focals) // 2] if focals else cfg.default_focal_factor * max(first.width, first.height)
        model = lens.auto_model([i.projection for i in members]) if cfg.camera_model == "auto" else cfg.camera_model
        cameras.append({"id": cam_id, "model": model, "width": first.width, "height": first.height,
                        "focal": focal, "prior_focal": prior and model not in lens.SPHERICAL_MODELS})
        for info in members:
            image_camera[info.name] = cam_id
    return cameras, image_camera


def _duplicates(ctx: StageContext, named) -> list[list[str]]:
    by_digest: dict[str, list[str]] = defaultdict(list)
    for path, name in named:  # hashes remembered when the cache key was computed
        by_digest[ctx.digest(path)].append(name)
    return [names for names in by_digest.values() if len(names) > 1]
