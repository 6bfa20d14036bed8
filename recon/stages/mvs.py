"""mvs: depth and normal maps per view: recon's CPU PatchMatch, or COLMAP's CUDA PatchMatch when present.

Photos added to a workspace (CPU backend): each view's final depth and normal maps, and its
photometric depth map (which its neighbours' geometric pass reads), are kept in the item store
(:mod:`recon.items`), keyed by what determines them, cameras compared within ``reuse_max_shift``
(:mod:`recon.mvs.reuse`). A view keeps the sources it had in the previous run while they all still
qualify and no other view now ranks among its ``reselect_top`` best (default 0: while they qualify;
:func:`recon.mvs.views.select_problems`), and reuses its final maps. A view that takes new sources
starts from the photometric maps its old sources gave (kept in the store, the normals as float16)
and runs only the geometric pass, against its new sources: the photometric pass costs about nine
times the geometric one at 320x240, twice at 640x480, and the final maps then see the new photo (zoo classic 320x240, 20 + 4
views: final maps kept from the old sources covered 0.915 of the true surface's pixels, from-scratch
maps 0.946, maps checked again against the new sources 0.932). So a new photo costs its own
photometric maps and a geometric pass for each view whose sources it changes. ``views.json`` records each view's sources,
whether its final maps were reused, and whether its photometric maps were.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from recon.config import to_dict
from recon.files import read_json, write_json
from recon.imaging.masks import mask_path
from recon.items import ItemStore
from recon.mvs.colmap_cuda import cuda_available, run_patch_match
from recon.mvs.colmap_io import read_normal_map, write_map
from recon.mvs.options import MVSOptions
from recon.options import opt, output_options
from recon.products import DenseScene, DepthMaps, PreparedPhotos, SparseModel
from recon.stage import Stage, StageContext, StageError, register

VIEWS = "views.json"  # in the output folder: per view, its sources and whether its maps were reused
#: the item stores of the stage (:mod:`recon.items`): photometric depth, its normals (float16), its per-pixel
#: source masks, final maps
_STORES = {"photometric": ".bin", "photometric_normal": ".npy", "photometric_sources": ".npz", "depth": ".bin",
           "normal": ".bin"}


@dataclass(frozen=True)
class MvsConfig(MVSOptions):
    backend: Literal["auto", "cpu", "colmap-cuda"] = opt(
        "auto", "cpu = recon's PatchMatch; colmap-cuda = COLMAP's (needs pycolmap-cuda12 and an NVIDIA GPU); "
                "auto = colmap-cuda when available, else cpu")
    reuse_max_shift: float = opt(
        0.5, "cpu: an earlier run's depth map of a view is reused when its sources moved relative to it, and the "
             "cameras' intrinsics, by less than this (px at the working resolution; filtering and fusion ask 1 px "
             "of agreement)", ge=0.0)
    reselect_top: int = opt(
        0, "cpu, photos added: a view keeps the sources it had, and its final maps, unless a view it did not use "
           "now ranks among its best this many; then it takes its new sources and runs the geometric pass again "
           "from the photometric maps its old ones gave. 0 = keeps them while they qualify. Zoo classic 640x480, "
           "20 + 4 views: 0 reuses 20 of 24 final maps, 0.39 of the from-scratch time, fused / mesh F@0.2% 0.003 / "
           "0.009 below from scratch; 8 re-checks all 20 against new sources, 0.52 of the time, 0.001 / 0.011 "
           "below. At 320x240, 0 was 0.017 below in fused F, 8 0.006: raise it for small photos",
        ge=0, le=32)
    keep_photometric: bool = opt(
        False, "keep each view's photometric depth and normal maps (<image>.photometric.bin) and source "
               "masks (source_masks/<image>.photometric.npz) beside its final (geometric) ones; no later stage "
               "reads them and they double the stage's size. With it, every view is computed afresh")


def backend_of(cfg: MvsConfig) -> str:
    """The backend that runs: ``auto`` resolved on this machine (part of the cache key)."""
    if cfg.backend == "auto":
        return "colmap-cuda" if cuda_available() else "cpu"
    return cfg.backend


def _view_pass(task) -> str:
    """One view's photometric or geometric pass, in a worker process."""
    from recon.logs import quiet_colmap
    from recon.mvs import stereo

    quiet_colmap()
    pass_name, dense, problem, options, out = task
    view = stereo.photometric_view if pass_name == "photometric" else stereo.geometric_view
    return str(view(dense, problem, options, out))


@register
class Mvs(Stage):
    name = "mvs"
    version = 17
    Config = MvsConfig
    requires = (DenseScene, SparseModel, PreparedPhotos)  # the photos and their cameras key the maps kept
    produces = DepthMaps
    uses_seed = True
    summary = "PatchMatch multi-view stereo: per-view depth and normal maps, consistency-filtered"

    def fingerprint(self, ctx: StageContext, cfg: MvsConfig):
        """The resolved backend: depth maps made by COLMAP's CUDA PatchMatch are not recon's."""
        return {"backend": backend_of(cfg)}

    def run(self, ctx: StageContext, cfg: MvsConfig) -> dict:
        dense = ctx.input(DenseScene)
        stereo = ctx.output.folder
        stereo.mkdir(exist_ok=True)
        for name in ("patch-match.cfg", "fusion.cfg"):
            if (dense.stereo_configs / name).exists():
                shutil.copyfile(dense.stereo_configs / name, stereo / name)
        if backend_of(cfg) == "colmap-cuda":
            return self._colmap_cuda(ctx, dense, stereo, cfg)
        return self._cpu(ctx, dense, stereo, cfg)

    def _cpu(self, ctx: StageContext, dense: DenseScene, stereo: Path, cfg: MvsConfig) -> dict:
        from recon.mvs import reuse
        from recon.mvs.stereo import map_path, sources_path

        workers = max(1, min(ctx.executor.workers, len(os.sched_getaffinity(0))))
        threads = cfg.num_threads or max(1, len(os.sched_getaffinity(0)) // workers)
        plan = _plan(ctx, dense, cfg)
        options = replace(plan.options, num_threads=threads)
        if not plan.problems:
            raise StageError("mvs: no view has source views with enough shared points and baseline")
        names = [p.ref for p in plan.problems]
        for name in plan.reused:
            for kind in ("depth", "normal"):
                dest = map_path(stereo, kind, name, "geometric")
                if not dest.exists():
                    plan.stores[kind].link(plan.geometric[name].key, dest)
        todo = [p for p in plan.problems if p.ref not in plan.reused]
        refs = {p.ref for p in todo}
        needed = refs | {s for p in todo for s in p.sources if s in plan.photometric}
        kept = set()  # forced: every map computed again
        if ctx.reuse:
            kept = {name for name in needed if _link_photometric(plan, stereo, name, own=name in refs)}
        for name in plan.earlier - kept:  # its earlier photometric maps went missing: computed with its new sources
            plan.photometric[name] = plan.fresh[name]
        plan.geometric = reuse.geometric_items(plan.problems, plan.photometric, plan.inputs, plan.options)
        photometric = [p for p in plan.problems if p.ref in needed and p.ref not in kept]  # some done, if resumed
        if plan.reused:
            ctx.log.info("mvs: depth maps of %d of %d views reused from earlier runs", len(plan.reused), len(names))
        for pass_name, problems in (("photometric", photometric), ("geometric", todo)):
            # every needed view's photometric maps before any geometric pass
            ctx.map(_view_pass, [(pass_name, dense.folder, p, options, stereo) for p in problems],
                    desc=f"mvs {pass_name}", done=lambda t: map_path(stereo, "depth", t[2].ref, t[0]).exists())
            _apply_masks(ctx, dense, stereo, [p.ref for p in problems], pass_name)
        for p in photometric:
            item = plan.photometric[p.ref]
            plan.stores["photometric"].put(item.key, map_path(stereo, "depth", p.ref, "photometric"), item.meta)
            normal = read_normal_map(map_path(stereo, "normal", p.ref, "photometric")).astype(np.float16)
            plan.stores["photometric_normal"].write(item.key, lambda tmp, n=normal: _save(tmp, n))
            plan.stores["photometric_sources"].put(item.key, sources_path(stereo, p.ref))
        for p in todo:
            item = plan.geometric[p.ref]
            plan.stores["normal"].put(item.key, map_path(stereo, "normal", p.ref, "geometric"))
            plan.stores["depth"].put(item.key, map_path(stereo, "depth", p.ref, "geometric"), item.meta)
        write_json(ctx.out / VIEWS, {p.ref: {"sources": list(p.sources), "reused": p.ref in plan.reused,
                                             "photometric_reused": p.ref in plan.reused or p.ref in kept}
                                     for p in plan.problems})
        if not cfg.keep_photometric:
            _drop_photometric(ctx, stereo)
        return {**_coverage(stereo, names, backend="cpu"), "reused": len(plan.reused), "computed": len(todo),
                "photometric_computed": len(photometric),
                "photometric_reused": len(kept & refs)}

    def reusable(self, ctx: StageContext, cfg: MvsConfig) -> str | None:
        if backend_of(cfg) != "cpu":
            return None
        plan = _plan(ctx, ctx.input(DenseScene), cfg)
        return (f"reuses the depth maps of {len(plan.reused)} of {len(plan.problems)} views"
                + (f" and the photometric maps of {len(plan.earlier)} more" if plan.earlier else ""))

    def _colmap_cuda(self, ctx: StageContext, dense: DenseScene, stereo: Path, cfg: MvsConfig) -> dict:
        """Thin adapter: COLMAP's own PatchMatch on the GPU, writing into this stage's folder."""
        if not cuda_available():
            raise StageError("mvs.backend: 'colmap-cuda' needs `pip install recon[cuda]` (pycolmap-cuda12) and "
                             "an NVIDIA GPU; use 'cpu' or 'auto'")
        scratch = ctx.out / "colmap"  # COLMAP's layout: the undistorted images and model, this stage's stereo/
        scratch.mkdir(exist_ok=True)
        for target in (dense.images, dense.model, stereo):
            link = scratch / target.name
            if not link.exists():
                link.symlink_to(target)
        run_patch_match(scratch, replace(cfg, seed=cfg.seed + ctx.seed))
        names = [p.stem.removesuffix(".geometric") for p in (stereo / "depth_maps").glob("*.geometric.bin")]
        _apply_masks(ctx, dense, stereo, names, "geometric")
        if not cfg.keep_photometric:
            _drop_photometric(ctx, stereo)
        return _coverage(stereo, names, backend="colmap-cuda")


@dataclass
class _Plan:
    """Each view's problem (sources, depth range), the items of its maps, and which it can reuse."""

    options: MvsConfig  # the run's seed added
    problems: list
    inputs: dict  # view -> recon.mvs.reuse.ViewInput
    fresh: dict  # view -> recon.mvs.reuse.MapItem of its photometric maps made with its sources now
    photometric: dict  # view -> MapItem of the photometric maps it uses: fresh, or made with its earlier sources
    geometric: dict  # view -> MapItem of its final depth and normal maps
    stores: dict[str, ItemStore]  # "photometric" (depth), "photometric_normal", "depth" and "normal" (final)
    earlier: set[str] = field(default_factory=set)  # views whose photometric maps are their earlier sources'
    reused: set[str] = field(default_factory=set)

    def holds(self, kind: str, item) -> bool:
        """Whether the store of ``kind`` has ``item`` whole, made with cameras within the tolerance."""
        from recon.mvs.reuse import reusable

        o = self.options
        return self.stores[kind].get(item.key) is not None and reusable(
            self.stores[kind].meta(item.key), item.meta, o.reuse_max_shift, o.depth_margin, o.max_image_size)


def _plan(ctx: StageContext, dense: DenseScene, cfg: MvsConfig) -> _Plan:
    """Select every view's sources (keeping those of the previous run where they still qualify) and
    find which views' final maps the item store holds (:mod:`recon.mvs.reuse`)."""
    import pycolmap

    from recon.mvs import reuse
    from recon.mvs.views import select_problems, view_camera

    options = replace(cfg, seed=cfg.seed + ctx.seed)
    model = pycolmap.Reconstruction(str(dense.model))
    previous = _previous_sources(ctx, cfg) if ctx.reuse else {}
    problems = select_problems(model, options, keep=previous or None, reselect_top=cfg.reselect_top)
    photos, sparse = ctx.input(PreparedPhotos), pycolmap.Reconstruction(str(ctx.input(SparseModel).model()))
    originals = {image.name: sparse.cameras[image.camera_id] for image in sparse.images.values()}
    inputs = {}
    for image in model.images.values():
        if not image.has_pose:
            continue
        name, original = image.name, originals.get(image.name)
        # a photo's own file and camera; a view made from part of a photo (a 360 photo's cube face) by its pixels
        picture = photos.geometric / name if original is not None else dense.images / name
        mask = mask_path(photos.masks, name) if original is not None else mask_path(dense.masks, name)
        inputs[name] = reuse.ViewInput(ctx.digest(picture), ctx.digest(mask) if mask.is_file() else None,
                                       reuse.camera_record(view_camera(image, model.camera(image.camera_id)),
                                                           original))
    fresh = reuse.photometric_items(problems, inputs, options)
    folder = ctx.workspace.items_dir("mvs")
    stores = {kind: ItemStore(folder / kind, suffix) for kind, suffix in _STORES.items()}
    plan = _Plan(options, problems, inputs, fresh, dict(fresh), {}, stores)
    if ctx.reuse and not cfg.keep_photometric:
        for p in problems:  # a view with new sources starts from the photometric maps its earlier ones gave
            before = previous.get(p.ref)
            if before and before != p.sources and all(s in inputs for s in before):
                item = reuse.photometric_items([replace(p, sources=before)], inputs, options)[p.ref]
                if plan.holds("photometric", item) and stores["photometric_normal"].get(item.key) is not None:
                    plan.photometric[p.ref] = item
                    plan.earlier.add(p.ref)
    plan.geometric = reuse.geometric_items(problems, plan.photometric, inputs, options)
    if ctx.reuse and not cfg.keep_photometric:
        plan.reused = {p.ref for p in problems if plan.holds("depth", plan.geometric[p.ref])
                       and stores["normal"].get(plan.geometric[p.ref].key) is not None}
    plan.earlier -= plan.reused
    return plan


def _link_photometric(plan: _Plan, stereo: Path, name: str, own: bool) -> bool:
    """Put the view's photometric depth map from the store into ``stereo`` (and, when its ``own``
    geometric pass is to run, its normal map and source masks); whether it was there."""
    from recon.mvs.stereo import map_path, sources_path

    item = plan.photometric[name]
    depth = map_path(stereo, "depth", name, "photometric")
    normal = plan.stores["photometric_normal"].get(item.key) if own else None
    masks = plan.stores["photometric_sources"].get(item.key) if own else None
    if depth.exists() or not plan.holds("photometric", item) or (own and (normal is None or masks is None)):
        return False
    if not plan.stores["photometric"].link(item.key, depth):
        return False
    if own:
        sources = sources_path(stereo, name)
        sources.parent.mkdir(exist_ok=True)
        plan.stores["photometric_sources"].link(item.key, sources)
        normals = np.load(normal, allow_pickle=False).astype(np.float32)
        normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-12)
        write_map(map_path(stereo, "normal", name, "photometric"), normals)
    return True


def _save(path: Path, array: np.ndarray) -> None:
    """``array`` as .npy at ``path`` exactly (np.save given a path would append ".npy" to a temporary name)."""
    with path.open("wb") as f:
        np.save(f, array)


def _previous_sources(ctx: StageContext, cfg: MvsConfig) -> dict[str, tuple[str, ...]]:
    """Each view's sources in the newest earlier output of this stage made with the same options and
    photometric maps made as now (a stage version from reuse.PHOTOMETRIC_VERSION on)."""
    from recon.mvs import reuse

    config = to_dict(output_options(cfg))
    for manifest in reversed(ctx.workspace.manifests(Mvs.name)):
        version = manifest.get("version")
        if isinstance(version, int) and reuse.PHOTOMETRIC_VERSION <= version <= Mvs.version \
                and (manifest.get("seed"), manifest.get("config")) == (ctx.seed, config):
            views = read_json(ctx.workspace.output_dir(Mvs.name, manifest.get("key", "")) / VIEWS)
            if isinstance(views, dict):
                return {name: tuple(v["sources"]) for name, v in views.items()
                        if isinstance(v, dict) and isinstance(v.get("sources"), list)}
    return {}


def _apply_masks(ctx: StageContext, dense: DenseScene, stereo: Path, names: list[str], pass_name: str) -> None:
    """Clear the depths of masked pixels (photos with masks): after the photometric pass, so that the
    geometric pass does not check consistency against them, and after the geometric pass."""
    from recon.mvs.stereo import map_path, mask_maps

    cleared = 0
    for name in names:
        mask = dense.mask(name)
        if mask is not None and map_path(stereo, "depth", name, pass_name).exists():
            cleared += mask_maps(stereo, name, mask, pass_name)
    if cleared:
        ctx.log.info("mvs: %s depths of %d masked pixels cleared", pass_name, cleared)


def _drop_photometric(ctx: StageContext, stereo: Path) -> None:
    """Delete the photometric depth and normal maps and source masks of every view that has its final
    (geometric) maps, before the manifest lists the output's files: only the geometric pass reads them,
    and a later run finds those it needs in the item store (hard links: deleting these frees what the
    store does not keep). A view with photometric maps only (COLMAP's backend with ``geometric``
    off) keeps them: they are its final maps."""
    from recon.mvs.stereo import SOURCE_MASKS, map_path, sources_path

    dropped = 0
    for depth in sorted((stereo / "depth_maps").glob("*.photometric.bin")):
        name = depth.name.removesuffix(".photometric.bin")
        if map_path(stereo, "depth", name, "geometric").exists():
            depth.unlink()
            map_path(stereo, "normal", name, "photometric").unlink(missing_ok=True)
            sources_path(stereo, name).unlink(missing_ok=True)
            dropped += 1
    with contextlib.suppress(OSError):  # the stage's own folder, left while it holds a view's masks
        (stereo / SOURCE_MASKS).rmdir()
    if dropped:
        ctx.log.info("mvs: photometric maps of %d views dropped (mvs.keep_photometric keeps them)", dropped)


def _coverage(stereo: Path, names: list[str], backend: str) -> dict:
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.stereo import map_path

    kept = [float(np.count_nonzero(d)) / d.size for d in
            (read_depth_map(map_path(stereo, "depth", n, "geometric")) for n in names)]
    return {"backend": backend, "views": len(names), "kept_pixels": round(float(np.mean(kept)) if kept else 0.0, 3)}
