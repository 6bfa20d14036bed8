"""preprocess: the 2D operations of ``preprocess.ops``, exposure-bracket merging and masks.

Operations come from :data:`recon.imaging.ops.OPS`, in the order listed, each with its own typed
options: ``ops: [{op: bilateral}, {op: clahe, clip_limit: 3.0}]``. Brackets (``preprocess.brackets``)
are merged into one image per view before the operations. Outputs:

- ``images/``: every operation applied: what features and matching see;
- ``images_geometric/``: only the geometric operations (resize, undistort), so the original colours
  in the geometry of ``images/``: what dense matching and texturing read (published as the
  workspace's ``images/``);
- ``masks/<image name>.png``: the masks of ``preprocess.mask_dir`` warped like the images (COLMAP's
  convention; zero = ignore); features drop keypoints where they are zero;
- ``images.json``: ingest's list with the cameras of the output pixels: geometric operations change
  them (:class:`recon.imaging.intrinsics.Intrinsics`), a calibration (stage ``calibrate``) replaces
  ingest's guesses and marks them ``fixed`` or a prior for SfM.

When nothing changes the pixels, both image folders are links to ingest's images (no copy). Work is
one task per view through the executor; a view is done when its record file exists, so a killed run
resumes with the views left.
"""

from __future__ import annotations

import difflib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image

from recon.config import ConfigError, build, to_dict
from recon.files import atomic, read_json, write_json
from recon.imaging.hdr import exposure_time, group_by_exposure, group_by_name, merge_brackets
from recon.imaging.intrinsics import Intrinsics
from recon.imaging.masks import load_mask, save_mask
from recon.imaging.ops import OPS, Step, apply_chain
from recon.options import opt
from recon.products import Calibration, Photos, PreparedPhotos
from recon.sparse.database import camera_params
from recon.sparse.photos import read_upright
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class BracketConfig:
    group_by: Literal["exposure", "name"] = opt(
        "exposure", "exposure: consecutive photos with distinct EXIF exposure times form a bracket; "
                    "name: photos whose names share the view id captured by `regex`")
    regex: str = opt(r"(?P<view>.+)_ev[-+]?\d+", "name: regular expression searched in file names; its group "
                                                  "`view` (or first group) is the view id")
    size: int = opt(0, "exposure: photos per bracket; 0 = a bracket ends when an exposure time repeats", ge=0)
    method: Literal["mertens", "debevec"] = opt("mertens", "mertens: exposure fusion, needs no exposure times; "
                                                           "debevec: radiance from EXIF times, then tone-mapped")
    align: bool = opt(True, "align hand-held brackets by whole-pixel shifts (median threshold bitmaps)")


@dataclass(frozen=True)
class PreprocessConfig:
    ops: list[Any] = opt([], "ordered image operations, each {op: NAME, OPTION: VALUE, ...}; NAME is one of "
                             + ", ".join(OPS))
    brackets: BracketConfig | None = opt(None, "merge exposure brackets into one image per view (before ops)")
    mask_dir: str | None = opt(None, "folder of masks <mask_dir>/<image name>.png (zero = ignore); relative "
                                     "to the config file")
    jpeg_quality: int = opt(95, "quality of processed images written as JPEG (names keep their format)",
                            ge=50, le=100)

    def __post_init__(self):
        # Spell every option out, so the cache key does not depend on whether defaults were written.
        object.__setattr__(self, "ops", [_checked_op(i, entry) for i, entry in enumerate(self.ops)])

    def steps(self) -> list[Step]:
        """The operations as (name, options instance) steps for :func:`recon.imaging.ops.apply_chain`."""
        return [(e["op"], build(OPS[e["op"]].Options, {k: v for k, v in e.items() if k != "op"})) for e in self.ops]


def _checked_op(index: int, entry: Any) -> dict:
    path = f"preprocess.ops[{index}]"
    if not isinstance(entry, dict):
        raise ConfigError(f"{path}: expected a mapping like {{op: clahe, clip_limit: 3.0}}, got {entry!r}")
    if "op" not in entry:
        raise ConfigError(f"{path}: no `op` key; name the operation, one of {', '.join(OPS)}")
    name = entry["op"]
    if name not in OPS:
        close = difflib.get_close_matches(str(name), list(OPS), n=1, cutoff=0.5)
        hint = f"did you mean '{close[0]}'?" if close else f"operations: {', '.join(OPS)}"
        raise ConfigError(f"{path}.op: unknown operation {name!r}; {hint}")
    options = build(OPS[name].Options, {k: v for k, v in entry.items() if k != "op"}, path)
    return {"op": name, **to_dict(options)}


@dataclass(frozen=True)
class _View:
    """One output image: a photo, or the merged photos of one exposure bracket."""

    name: str
    members: tuple[str, ...]  # ingest image names
    camera: int  # ingest camera id
    times: tuple[float, ...] | None


@dataclass(frozen=True)
class _Task:
    view: _View
    sources: tuple[Path, ...]
    camera: Intrinsics  # of the source pixels
    steps: tuple[Step, ...]
    brackets: BracketConfig | None
    write_images: bool  # False: images/ is a link to ingest's images
    write_geometric: bool  # False: images_geometric/ is a link to ingest's images
    mask: Path | None  # the view's mask file in mask_dir
    out: Path
    jpeg_quality: int

    @property
    def record(self) -> Path:
        return self.out / "items" / f"{self.view.name}.json"


@register
class Preprocess(Stage):
    name = "preprocess"
    version = 1
    Config = PreprocessConfig
    requires = (Photos, Calibration)
    produces = PreparedPhotos
    summary = "2D operations (resize, undistort, denoise, contrast, deblur), bracket merging and masks"

    def fingerprint(self, ctx: StageContext, cfg: PreprocessConfig):
        folder = _mask_folder(ctx, cfg)
        if folder is None:
            return None
        return [[p.relative_to(folder).as_posix(), ctx.digest(p)] for p in sorted(folder.rglob("*.png"))]

    def run(self, ctx: StageContext, cfg: PreprocessConfig) -> dict:
        photos = ctx.input(Photos)
        listing = photos.listing()
        calibration = _calibration(ctx.input(Calibration))
        steps = tuple(cfg.steps())
        if calibration is None and any(name == "undistort" for name, _ in steps):
            raise StageError("preprocess.ops: 'undistort' needs the photos' distortion, which only a calibration "
                             "gives: set calibrate.images to a folder of chessboard photos")
        sources = _source_cameras(listing, calibration)
        views = _views(listing, cfg.brackets, photos.images)
        geometric = any(OPS[name].geometric for name, _ in steps)
        write_images = bool(steps) or cfg.brackets is not None
        write_geometric = geometric or cfg.brackets is not None
        for folder, written in (("images", write_images), ("images_geometric", write_geometric)):
            if not written:
                _link(ctx.out / folder, photos.images)
        masks = _mask_folder(ctx, cfg)
        tasks = [_Task(view, tuple(photos.images / m for m in view.members), sources[view.camera], steps,
                       cfg.brackets, write_images, write_geometric, _mask_of(masks, view), ctx.out,
                       cfg.jpeg_quality) for view in views]
        if write_images or masks is not None:
            ctx.map(_process_view, tasks, desc="preprocess", done=lambda t: t.record.is_file())
            records = [read_json(t.record) for t in tasks]
        else:
            records = [{"camera": _camera_json(t.camera), "masked": False} for t in tasks]
        result = _listing(listing, views, records, calibration)
        ctx.output.write_listing(result)
        shutil.rmtree(ctx.out / "items", ignore_errors=True)
        cams = result["cameras"]
        return {"images": len(views), "operations": len(steps), "merged_brackets": len(listing["images"]) - len(views),
                "masked": sum(1 for r in records if r["masked"]), "cameras": len(cams),
                "size": f"{cams[0]['width']}x{cams[0]['height']}", "fixed_cameras": sum(c["fixed"] for c in cams)}


# ---------------------------------------------------------------------------------------------
# Planning: views, cameras, masks


def _mask_folder(ctx: StageContext, cfg: PreprocessConfig) -> Path | None:
    return ctx.user_path("mask_dir", cfg.mask_dir, "give the folder that holds <image name>.png masks", folder=True)


def _mask_of(masks: Path | None, view: _View) -> Path | None:
    """The view's mask file: named for the view, else for its first photo (brackets); None if absent."""
    if masks is None:
        return None
    for name in (view.name, view.members[0]):
        path = masks / f"{name}.png"
        if path.is_file():
            return path
    return None


def _calibration(product: Calibration) -> tuple[Intrinsics, str] | None:
    """The calibrated camera and its ``use`` (fixed / prior), or None when nothing was calibrated."""
    data = product.read()
    if data is None:
        return None
    return Intrinsics(data["model"], data["width"], data["height"], tuple(data["params"])), data["use"]


def _source_cameras(listing: dict, calibration: tuple[Intrinsics, str] | None) -> dict[int, Intrinsics]:
    """Ingest camera id -> the camera of its photos: ingest's guess, or the calibration at the photos' size."""
    cameras = {}
    for cam in listing["cameras"]:
        w, h = cam["width"], cam["height"]
        if calibration is None:
            cameras[cam["id"]] = Intrinsics(cam["model"], w, h, camera_params(cam["model"], w, h, cam["focal"]))
            continue
        calibrated = calibration[0]
        if (w, h) == (calibrated.width, calibrated.height):
            cameras[cam["id"]] = calibrated
        elif abs(w * calibrated.height - h * calibrated.width) <= max(w, h) / 200:  # same shape, resized
            cameras[cam["id"]] = calibrated.scaled(w, h)
        else:
            raise StageError(f"calibrate: the calibration photos are {calibrated.width}x{calibrated.height} but "
                             f"photos of camera {cam['id']} are {w}x{h} (another shape); calibrate with photos "
                             "taken like the scene's")
    return cameras


def _views(listing: dict, brackets: BracketConfig | None, images: Path) -> list[_View]:
    entries = {img["name"]: img for img in listing["images"]}
    if brackets is None:
        return [_View(name, (name,), img["camera"], None) for name, img in entries.items()]
    by_folder: dict[str, list[str]] = {}
    for name in entries:
        by_folder.setdefault(name.rpartition("/")[0], []).append(name)
    views = []
    for folder, names in by_folder.items():
        paths = [images / n for n in names]
        try:
            groups = group_by_exposure(paths, brackets.size) if brackets.group_by == "exposure" else \
                group_by_name(paths, brackets.regex)
        except ValueError as exc:
            raise StageError(f"preprocess.brackets: {exc}") from None
        for group in groups:
            members = tuple(p.relative_to(images).as_posix() for p in group.paths)
            first = entries[members[0]]
            if len({(entries[m]["width"], entries[m]["height"]) for m in members}) > 1:
                raise StageError(f"preprocess.brackets: the photos of bracket {group.view!r} differ in size: "
                                 f"{', '.join(members)}")
            times = group.exposure_times
            if brackets.method == "debevec" and len(members) > 1 and times is None:
                times = tuple(exposure_time(images / m) for m in members)
                if any(t is None for t in times):
                    raise StageError(f"preprocess.brackets: 'debevec' needs EXIF exposure times, which bracket "
                                     f"{group.view!r} lacks; use method: mertens")
            name = (f"{folder}/" if folder else "") + group.view + Path(members[0]).suffix
            if len(members) == 1:
                name = members[0]
            views.append(_View(name, members, first["camera"], times))
    return views


def _camera_json(camera: Intrinsics) -> dict:
    return {"model": camera.model, "width": camera.width, "height": camera.height, "params": list(camera.params)}


def _listing(listing: dict, views: list[_View], records: list[dict], calibration) -> dict:
    """ingest's images.json for the output images: one camera per (ingest camera, output intrinsics)."""
    ingest_cameras = {c["id"]: c for c in listing["cameras"]}
    entries = {img["name"]: img for img in listing["images"]}
    fixed = calibration is not None and calibration[1] == "fixed"
    cameras: list[dict] = []
    ids: dict[tuple, int] = {}
    images = []
    for view, record in zip(views, records):
        cam = record["camera"]
        key = (view.camera, cam["model"], cam["width"], cam["height"], tuple(round(p, 9) for p in cam["params"]))
        if key not in ids:
            ids[key] = len(cameras) + 1
            source = ingest_cameras[view.camera]
            cameras.append({"id": ids[key], **cam, "focal": cam["params"][0],
                            "prior_focal": bool(source["prior_focal"]) or calibration is not None, "fixed": fixed})
        first = entries[view.members[0]]
        scale = cam["width"] / first["width"]
        entry = {**first, "name": view.name, "width": cam["width"], "height": cam["height"], "camera": ids[key],
                 "focal_px": first["focal_px"] * scale if first["focal_px"] else None, "masked": record["masked"]}
        if len(view.members) > 1:
            entry["sources"] = list(view.members)
        images.append(entry)
    return {"images": images, "cameras": cameras, "ordered": bool(listing.get("ordered", False)),
            "calibrated": calibration is not None}


def _link(dest: Path, target: Path) -> None:
    """``dest`` as a relative symlink to ``target`` (both inside the cache, so the link survives moves)."""
    if dest.is_symlink() or dest.exists():
        dest.unlink()
    os.symlink(os.path.relpath(target, dest.parent), dest)


# ---------------------------------------------------------------------------------------------
# One view (runs in a worker process)


def _process_view(task: _Task) -> None:
    view, out = task.view, task.out
    image = _read_view(task)
    mask = None
    if task.mask is not None:
        try:
            mask = load_mask(task.mask.parent, task.mask.name.removesuffix(".png"), image.shape[:2])
        except ValueError as exc:
            raise StageError(f"preprocess.mask_dir: {exc}") from None
    camera = task.camera
    if task.write_images:
        processed, camera_out, mask_out = apply_chain(image, camera, task.steps, mask)
        _save(out / "images" / view.name, processed, task.jpeg_quality)
    else:
        processed, camera_out, mask_out = image, camera, mask
    if task.write_geometric:
        geometric = [s for s in task.steps if OPS[s[0]].geometric]
        if len(geometric) < len(task.steps):
            processed, _, _ = apply_chain(image, camera, geometric)
        _save(out / "images_geometric" / view.name, processed, task.jpeg_quality)
    if mask_out is not None:
        save_mask(out / "masks", view.name, mask_out)
    write_json(task.record, {"camera": _camera_json(camera_out), "masked": mask_out is not None})


def _read_view(task: _Task) -> np.ndarray:
    images = [np.asarray(read_upright(p)) for p in task.sources]
    if len(images) == 1:
        return images[0]
    return merge_brackets(images, task.view.times, method=task.brackets.method, align=task.brackets.align)


def _save(path: Path, image: np.ndarray, jpeg_quality: int) -> None:
    """Write ``image`` in the format its name says, atomically."""
    jpeg = path.suffix.lower() in (".jpg", ".jpeg")
    with atomic(path) as tmp:
        Image.fromarray(image).save(tmp, **({"quality": jpeg_quality} if jpeg else {}))
