"""mvs: depth and normal maps per view: recon's CPU PatchMatch, or COLMAP's CUDA PatchMatch when present."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from recon.mvs.options import MVSOptions
from recon.options import opt
from recon.stage import Stage, StageContext, StageError, register


@dataclass(frozen=True)
class MvsConfig(MVSOptions):
    backend: Literal["auto", "cpu", "colmap-cuda"] = opt(
        "auto", "cpu = recon's PatchMatch; colmap-cuda = COLMAP's (needs pycolmap-cuda12 and an NVIDIA GPU); "
                "auto = colmap-cuda when available, else cpu")


def colmap_cuda_available() -> bool:
    """pycolmap built with CUDA and a GPU it can use (`pip install recon[cuda]`)."""
    try:
        import pycolmap

        devices = getattr(pycolmap, "get_num_cuda_devices", lambda: 1)  # absent in some builds
        return bool(pycolmap.has_cuda) and devices() > 0
    except ImportError:
        return False


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
    version = 1
    Config = MvsConfig
    requires = ("undistort",)
    outputs = ("stereo/depth_maps/<image>.{photometric,geometric}.bin", "stereo/normal_maps/...")
    publish = {"stereo": "dense/stereo"}
    uses_seed = True
    summary = "PatchMatch multi-view stereo: per-view depth and normal maps, consistency-filtered"

    def run(self, ctx: StageContext, cfg: MvsConfig) -> dict:
        dense = ctx.input("undistort") / "dense"
        stereo = ctx.out / "stereo"
        stereo.mkdir(exist_ok=True)
        for name in ("patch-match.cfg", "fusion.cfg"):
            if (dense / "stereo" / name).exists():
                shutil.copyfile(dense / "stereo" / name, stereo / name)
        backend = cfg.backend
        if backend == "auto":
            backend = "colmap-cuda" if colmap_cuda_available() else "cpu"
        if backend == "colmap-cuda":
            return self._colmap_cuda(ctx, dense, stereo, cfg)
        return self._cpu(ctx, dense, stereo, cfg)

    def _cpu(self, ctx: StageContext, dense: Path, stereo: Path, cfg: MvsConfig) -> dict:
        import pycolmap

        from recon.mvs.stereo import map_path
        from recon.mvs.views import select_problems

        workers = max(1, min(ctx.executor.workers, len(os.sched_getaffinity(0))))
        threads = cfg.num_threads or max(1, len(os.sched_getaffinity(0)) // workers)
        options = replace(cfg, seed=cfg.seed + ctx.seed, num_threads=threads)
        problems = select_problems(pycolmap.Reconstruction(str(dense / "sparse")), options)
        if not problems:
            raise StageError("mvs: no view has source views with enough shared points and baseline")
        for pass_name in ("photometric", "geometric"):  # every view's photometric maps before any geometric
            ctx.map(_view_pass, [(pass_name, dense, p, options, stereo) for p in problems],
                    desc=f"mvs {pass_name}", done=lambda t: map_path(stereo, "depth", t[2].ref, t[0]).exists())
        return _coverage(stereo, [p.ref for p in problems], backend="cpu")

    def _colmap_cuda(self, ctx: StageContext, dense: Path, stereo: Path, cfg: MvsConfig) -> dict:
        """Thin adapter: COLMAP's own PatchMatch on the GPU, writing into this stage's folder."""
        import pycolmap

        if not colmap_cuda_available():
            raise StageError("mvs.backend: 'colmap-cuda' needs `pip install recon[cuda]` (pycolmap-cuda12) and "
                             "an NVIDIA GPU; use 'cpu' or 'auto'")
        scratch = ctx.out / "colmap"
        scratch.mkdir(exist_ok=True)
        for name in ("images", "sparse"):
            link = scratch / name
            if not link.exists():
                link.symlink_to(dense / name)
        if not (scratch / "stereo").exists():
            (scratch / "stereo").symlink_to(stereo)
        opts = pycolmap.PatchMatchOptions()
        opts.max_image_size = cfg.max_image_size
        opts.window_radius = cfg.window_radius
        opts.geom_consistency = cfg.geometric
        opts.filter = True
        pycolmap.patch_match_stereo(str(scratch))
        names = [p.stem.removesuffix(".geometric") for p in (stereo / "depth_maps").glob("*.geometric.bin")]
        return _coverage(stereo, names, backend="colmap-cuda")


def _coverage(stereo: Path, names: list[str], backend: str) -> dict:
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.stereo import map_path

    kept = [float(np.count_nonzero(d)) / d.size for d in
            (read_depth_map(map_path(stereo, "depth", n, "geometric")) for n in names)]
    return {"backend": backend, "views": len(names), "kept_pixels": round(float(np.mean(kept)) if kept else 0.0, 3)}
