"""Benchmark of the CPU PatchMatch stereo: seconds per view, peak memory and depth accuracy.

Two workloads, each in a fresh process so its peak resident memory is its own:

* a synthetic scene (``recon.synth``, default 20 views at 640x480) with ground-truth depth: the
  share of kept pixels whose depth is within 1 % of the truth, and the share of the pixels with a
  true surface that are kept;
* fountain-P11 (Strecha) at 1536x1024 with its ground-truth cameras; its sparse model comes from
  SIFT matches triangulated with those poses (``gt_workspace.points_from_matches``).

Per view, "seconds" is the photometric plus the geometric pass (wall clock), "CPU s" their
processor time; the machine's other load shows as wall > CPU / threads, and in the load averages
printed before and after each workload. fountain-P11 is printed beside its references: OpenMVS 2.3
measured on these cores, and the target of at most 18 s per view. The figures are also written to
``mvs.json`` in the cache folder. Workspaces are cached in ``--cache`` (default ``$RECON_CACHE`` or
``~/.cache/recon``) and reused.

    python -m recon.mvs.bench [--synthetic-views 20] [--fountain-views 11] [--skip-fountain]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import multiprocessing
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from recon.mvs.options import MVSOptions
from recon.products import SparseModel

log = logging.getLogger(__name__)


def datasets_root() -> Path:
    """``$RECON_DATASETS``, else the shared datasets folder beside the repository."""
    env = os.environ.get("RECON_DATASETS")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "datasets"


def cache_root() -> Path:
    env = os.environ.get("RECON_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "recon"


def depth_scores(depth: np.ndarray, truth: np.ndarray, tolerance: float = 0.01) -> tuple[float, float]:
    """(accuracy, completeness) of a depth map against the truth at its resolution (0 = none):
    the share of kept pixels on a true surface within ``tolerance`` relative depth error, and the
    share of true-surface pixels kept."""
    if truth.shape != depth.shape:
        import cv2

        truth = cv2.resize(truth, depth.shape[::-1], interpolation=cv2.INTER_NEAREST)
    surface = truth > 0
    kept = (depth > 0) & surface
    if not kept.any():
        return 0.0, 0.0
    error = np.abs(depth[kept] - truth[kept]) / truth[kept]
    return float((error < tolerance).mean()), float(kept.sum() / max(surface.sum(), 1))


def prepare_synthetic(root: Path, views: int, width: int, height: int, seed: int = 0,
                      path: str = "orbit") -> Path:
    """Render the synthetic scene (``path`` 'orbit' or 'line') and build its dense workspace, the
    sparse points sampled on the true depth maps."""
    from recon.mvs.gt_workspace import make_dense_workspace, points_from_depths
    from recon.mvs.views import ViewCamera
    from recon.synth import load_scene, render_scene

    dense = root / "dense"
    if (dense / SparseModel.MODELS).exists():
        return dense
    if root.exists():
        shutil.rmtree(root)
    info = render_scene(root / "scene", views=views, width=width, height=height, seed=seed, path=path)
    cams = [ViewCamera(name, c.K, c.R, c.t, c.width, c.height) for name, c in info.cameras().items()]
    depths = [load_scene(info.root).depth(cam.name) for cam in cams]
    rec = points_from_depths(cams, depths, seed=seed)
    return make_dense_workspace(rec, info.images_dir, dense, root / "work")


def prepare_fountain(root: Path, dataset: Path) -> Path:
    """The dense workspace of fountain-P11 with its true cameras and SIFT points triangulated on them."""
    from recon.eval.groundtruth import load_cameras
    from recon.mvs.gt_workspace import make_dense_workspace, points_from_matches
    from recon.mvs.views import ViewCamera

    dense = root / "dense"
    if (dense / SparseModel.MODELS).exists():
        return dense
    cams = [ViewCamera(name, c.K, c.R, c.t, c.width, c.height)
            for name, c in sorted(load_cameras(dataset / "gt" / "gt_dense_cameras").items())]
    rec = points_from_matches(cams, dataset / "images", root / "work")
    return make_dense_workspace(rec, dataset / "images", dense, root / "work")


def run_views(dense: Path, options: MVSOptions, max_views: int) -> dict:
    """Both passes for the first ``max_views`` views (photometric also for their sources); per-view
    wall and CPU seconds, and this process's peak RSS."""
    import pycolmap

    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.stereo import SOURCE_MASKS, geometric_view, map_path, photometric_view
    from recon.mvs.views import select_problems

    out = dense / "stereo"
    for folder in ("depth_maps", "normal_maps", SOURCE_MASKS):
        shutil.rmtree(out / folder, ignore_errors=True)
    problems = select_problems(pycolmap.Reconstruction(dense / SparseModel.MODELS), options)
    measured = problems[:max_views]
    needed = {p.ref for p in measured} | {s for p in measured for s in p.sources}
    timings: dict[str, list[float]] = {}
    for problem in problems:
        if problem.ref in needed:
            wall, cpu = time.perf_counter(), time.process_time()
            photometric_view(dense, problem, options, out)
            timings[problem.ref] = [time.perf_counter() - wall, time.process_time() - cpu]
    for problem in measured:
        wall, cpu = time.perf_counter(), time.process_time()
        geometric_view(dense, problem, options, out)
        timings[problem.ref][0] += time.perf_counter() - wall
        timings[problem.ref][1] += time.process_time() - cpu
    per_view = [timings[p.ref] for p in measured]
    height, width = read_depth_map(map_path(out, "depth", measured[0].ref, "geometric")).shape
    return {"views": [p.ref for p in measured], "size": f"{width}x{height}", "wall": [w for w, _ in per_view],
            "cpu": [c for _, c in per_view],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _child(queue, target, args) -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    queue.put(target(*args))


def in_fresh_process(target, *args):
    """``target(*args)`` run in a spawned process (its own peak memory); returns its result."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(queue, target, args))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def _warm_up(options: MVSOptions) -> bool:
    """Compile (or load from numba's cache) the kernels so that timings exclude compilation."""
    from recon.mvs import patchmatch

    rng = np.random.default_rng(0)
    image = rng.random((48, 64)).astype(np.float32)
    K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    ref = patchmatch.Camera(K, np.eye(3), np.zeros(3))
    src = patchmatch.Camera(K, np.eye(3), np.array([-0.1, 0, 0]))
    small = dataclasses.replace(options, pyramid_levels=2, iterations=1, upper_iterations=1,
                                geometric_iterations=1)
    state = patchmatch.photometric_depth(image, [image], ref, [src], (1.0, 2.0), small, 0)
    view = patchmatch.checked(image, [image], ref, [src], [state.depth])
    state = patchmatch.geometric_depth(view, state, (1.0, 2.0), small, 0)
    patchmatch.filter_depth(view, state, small)
    return True


def synthetic_run(root: Path, views: int, width: int, height: int, options: MVSOptions) -> dict:
    """Timings and depth scores of the synthetic scene (in the calling process)."""
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.stereo import map_path
    from recon.synth import load_scene

    _warm_up(options)
    dense = prepare_synthetic(root, views, width, height)
    result = run_views(dense, options, views)
    info = load_scene(root / "scene")
    scores = [depth_scores(read_depth_map(map_path(dense / "stereo", "depth", name, "geometric")),
                           info.depth(name)) for name in result["views"]]
    result["accuracy"] = float(np.mean([a for a, _ in scores]))
    result["completeness"] = float(np.mean([c for _, c in scores]))
    return result


def fountain_run(root: Path, dataset: Path, max_views: int, options: MVSOptions) -> dict:
    """Timings of fountain-P11 (in the calling process)."""
    _warm_up(options)
    return run_views(prepare_fountain(root, dataset), options, max_views)


#: fountain-P11 at 1536x1024 with OpenMVS 2.3's DensifyPointCloud (CPU), measured once on these cores
OPENMVS_FOUNTAIN = {"s/view": 53.0, "peak_mb": 1150.0}
#: what recon's CPU PatchMatch must not exceed on fountain-P11 at 1536 px (issue 14)
TARGET_S_PER_VIEW = 18.0


def _row(label: str, result: dict) -> str:
    wall, cpu = np.array(result["wall"]), np.array(result["cpu"])
    acc = f"{100 * result['accuracy']:.1f}" if "accuracy" in result else "-"
    comp = f"{100 * result['completeness']:.1f}" if "completeness" in result else "-"
    return (f"| {label:<18} | {result['size']:>9} | {len(wall):>5} | {wall.mean():>8.1f} | {wall.max():>7.1f} | "
            f"{cpu.mean():>7.1f} | {result['peak_rss_mb']:>8.0f} | {acc:>8} | {comp:>8} |")


def _loaded(target, *args) -> dict:
    """``target(*args)`` in a fresh process, with the 1-minute load average before and after it."""
    before = os.getloadavg()[0]
    result = in_fresh_process(target, *args)
    return {**result, "load_before": before, "load_after": os.getloadavg()[0]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=None, help="workspace cache folder")
    parser.add_argument("--synthetic-views", type=int, default=20)
    parser.add_argument("--synthetic-size", default="640x480")
    parser.add_argument("--fountain-views", type=int, default=11, help="views whose time is measured")
    parser.add_argument("--skip-fountain", action="store_true")
    parser.add_argument("--skip-synthetic", action="store_true")
    parser.add_argument("--options", default="{}", help="JSON object of MVSOptions fields to override")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    options = dataclasses.replace(MVSOptions(), **json.loads(args.options))
    cache = (args.cache or cache_root()) / "mvs-bench"
    width, height = (int(v) for v in args.synthetic_size.split("x"))
    results = {}
    if not args.skip_synthetic:
        results["synthetic"] = _loaded(synthetic_run, cache / f"synthetic-{args.synthetic_views}-{width}x{height}",
                                       args.synthetic_views, width, height, options)
    dataset = datasets_root() / "fountain_p11"
    if not args.skip_fountain:
        if dataset.is_dir():
            results["fountain_p11"] = _loaded(fountain_run, cache / "fountain_p11", dataset, args.fountain_views,
                                              options)
        else:
            log.warning("fountain_p11 absent at %s: skipped", dataset)
    threads = options.num_threads or os.cpu_count()
    print(f"CPU PatchMatch stereo, {threads} threads, max_image_size {options.max_image_size}; "
          "s/view = photometric + geometric pass; accuracy = kept pixels within 1% depth; "
          "completeness = true-surface pixels kept")
    print("| workload           |      size | views | s/view   | max s   | CPU s   | peak MB  | acc %    | compl %  |")
    print("|--------------------|-----------|-------|----------|---------|---------|----------|----------|----------|")
    for label, result in results.items():
        print(_row(label, result))
    if "fountain_p11" in results:
        print(f"| {'OpenMVS 2.3':<18} | {'1536x1024':>9} | {'':>5} | {OPENMVS_FOUNTAIN['s/view']:>8.1f} | {'':>7} | "
              f"{'':>7} | {OPENMVS_FOUNTAIN['peak_mb']:>8.0f} | {'-':>8} | {'-':>8} |")
        per_view = float(np.mean(results["fountain_p11"]["wall"]))
        print(f"fountain_p11: {per_view:.1f} s/view against the target of at most {TARGET_S_PER_VIEW:.0f}: "
              f"{'met' if per_view <= TARGET_S_PER_VIEW else 'NOT met'}")
    for label, result in results.items():
        print(f"{label}: load average {result['load_before']:.1f} before, {result['load_after']:.1f} after, "
              f"on {os.cpu_count()} cores (above the core count, other work slowed it)")
    cache.mkdir(parents=True, exist_ok=True)
    (cache / "mvs.json").write_text(json.dumps({"options": dataclasses.asdict(options), **results}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
