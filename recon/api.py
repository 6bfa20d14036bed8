"""The Python API: everything the ``recon`` command does, as functions.

    import recon
    result = recon.run("pipelines/sparse.yaml", images="photos/", workspace="out/",
                       overrides={"features.max_image_size": 2000})
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from recon import pipeline
from recon.config import ConfigError
from recon.workspace import CACHE_DIR, Workspace, WorkspaceError, read_json, write_json

log = logging.getLogger("recon")
_last_log: list[Path] = []

REPO = Path(__file__).resolve().parents[1]
DEMO_CONFIG = REPO / "pipelines" / "demo.yaml"


def load(config: str | Path | dict | None, overrides: list[str] | dict | None = None, *,
         images: str | None = None, workspace: str | None = None) -> pipeline.RunConfig:
    """Read and validate a config; ``images``/``workspace`` replace the config's (paths from the cwd)."""
    cfg = pipeline.load_config(config, overrides)
    if images is not None or workspace is not None:
        from dataclasses import replace

        run = replace(cfg.run,
                      images=str(Path(images).absolute()) if images is not None else cfg.run.images,
                      workspace=str(Path(workspace).absolute()) if workspace is not None else cfg.run.workspace)
        cfg = pipeline.RunConfig(run, cfg.stages, cfg.base)
    return cfg


def run(config: str | Path | dict | None = None, *, images: str | None = None, workspace: str | None = None,
        overrides: list[str] | dict | None = None, from_stage: str | None = None, until: str | None = None,
        force: list[str] | tuple[str, ...] = (), verify: bool = False, **section_overrides: Any) -> pipeline.RunResult:
    """Run a pipeline. Keyword sections override config sections, e.g. ``features={"max_image_size": 1000}``."""
    merged: dict = dict(overrides) if isinstance(overrides, dict) else {}
    extra = list(overrides) if isinstance(overrides, list) else []
    for section, values in section_overrides.items():
        if isinstance(values, dict):
            merged.update({f"{section}.{k}": v for k, v in values.items()})
        else:
            merged[section] = values
    cfg = load(config, [*extra, *[f"{k}={_yaml(v)}" for k, v in merged.items()]], images=images,
               workspace=workspace)
    ws = Workspace(cfg.workspace)
    ws.create()
    _last_log[:] = [ws.meta / "recon.log"]
    from recon.logs import quiet_colmap

    quiet_colmap(ws.meta / "logs" / "colmap.")
    # written first, so that `recon status WS` can say where a killed run stopped
    write_json(ws.meta / "config.json", {"base": str(cfg.base), "config": cfg.as_dict()})
    return pipeline.run(cfg, from_stage=from_stage, until=until, force=force, verify=verify)


def _yaml(value: Any) -> str:
    import yaml

    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()


def _config_for(target: str | Path | dict, overrides=None, images=None, workspace=None) -> pipeline.RunConfig:
    if isinstance(target, dict):
        return load(target, overrides, images=images, workspace=workspace)
    path = Path(target)
    if path.is_dir():
        snapshot = read_json(path / CACHE_DIR / "config.json")
        if snapshot is None:
            raise WorkspaceError(f"{path}: not a recon workspace (no {CACHE_DIR}/config.json); pass the config file")
        data = snapshot["config"]
        data["workspace"] = str(path.absolute())
        cfg = load(data, overrides, images=images)
        return pipeline.RunConfig(cfg.run, cfg.stages, Path(snapshot["base"]))
    return load(path, overrides, images=images, workspace=workspace)


def status(target: str | Path | dict, overrides=None, images=None, workspace=None,
           verify: bool = False) -> list[pipeline.StageStatus]:
    return pipeline.status(_config_for(target, overrides, images, workspace), verify=verify)


def clean(target: str | Path, everything: bool = False, workspace: str | None = None) -> tuple[int, int]:
    path = Path(target)
    if path.is_dir():
        cfg = _config_for(path) if (path / CACHE_DIR / "config.json").exists() else None
        return pipeline.clean(cfg, path, everything)
    cfg = _config_for(path, workspace=workspace)
    return pipeline.clean(cfg, cfg.workspace, everything)


def last_log_file() -> Path | None:
    return _last_log[0] if _last_log else None


# ---------------------------------------------------------------------------------------------
# Evaluation, synthetic scenes, demo


def _estimated_poses(ws: Path, gt_cams: dict) -> dict:
    """World-to-camera (R, t) of ``<ws>/sparse/0``'s registered images, keyed by their ground-truth names."""
    import pycolmap

    model = ws / "sparse" / "0"
    if not (model / "images.bin").exists() and not (model / "images.txt").exists():
        raise WorkspaceError(f"{ws}: no sparse model at sparse/0; run the pipeline first")
    rec = pycolmap.Reconstruction(str(model))
    by_base = {Path(n).name: n for n in gt_cams}
    est = {}
    for image in rec.images.values():
        key = by_base.get(Path(image.name).name)
        if image.has_pose and key is not None:
            pose = image.cam_from_world()
            est[key] = (pose.rotation.matrix(), pose.translation)
    return est


def _load_gt(gt: str | Path) -> dict:
    from recon.eval.groundtruth import load_cameras

    try:
        return load_cameras(Path(gt))
    except (FileNotFoundError, ValueError) as exc:
        raise ConfigError(f"--gt {gt}: {exc}") from None


def model_to_ground_truth(workspace: str | Path, gt: str | Path):
    """The similarity taking the model's world to the ground truth's (robust fit on camera centres)."""
    gt_cams = _load_gt(gt)
    return _alignment(_estimated_poses(Path(workspace), gt_cams), gt_cams, gt)


def _alignment(est: dict, gt_cams: dict, gt: str | Path):
    import numpy as np

    from recon.geometry.transforms import align_similarity, camera_center

    if len(est) < 3:
        raise ConfigError(f"--gt {gt}: fewer than 3 images of the model have a ground-truth camera")
    names = sorted(est)
    src = np.array([camera_center(*est[n]) for n in names])
    dst = np.array([gt_cams[n].center for n in names])
    return align_similarity(src, dst, robust=True)[0]


def evaluate(workspace: str | Path, gt: str | Path) -> dict:
    """Figures of a workspace against ground truth: poses of ``sparse/0`` against the ground-truth
    cameras; on a synthetic scene also accuracy/completeness of the fused cloud and the mesh, after
    aligning the model to the ground truth by a robust similarity on the camera centres; with depth
    maps, the fused cloud's reprojection error into the ground-truth cameras."""
    from recon.eval.poses import pose_metrics

    ws = Path(workspace)
    gt_cams = _load_gt(gt)
    est = _estimated_poses(ws, gt_cams)
    if not est:
        raise ConfigError(f"--gt {gt}: no image of the model has a ground-truth camera there (names differ?)")
    figures: dict = {"poses": pose_metrics(est, gt_cams)}
    scene_file = Path(gt) / "gt" / "scene.json"
    surfaces = [(key, ws / rel) for key, rel in (("fused", "dense/fused.ply"), ("mesh", "mesh.ply"))
                if (ws / rel).exists()]
    reprojection = (ws / "dense" / "fused.ply").exists() and (ws / "dense" / "stereo" / "depth_maps").is_dir()
    sim = _alignment(est, gt_cams, gt) if len(est) >= 3 and (reprojection or scene_file.exists() and surfaces) else None
    if scene_file.exists() and surfaces and sim is not None:
        import numpy as np
        import trimesh

        from recon.eval.surface import surface_metrics
        from recon.synth import load_scene

        scene = load_scene(Path(gt))
        for key, path in surfaces:
            geometry = trimesh.load(path, process=False)
            geometry.vertices = sim.apply(np.asarray(geometry.vertices))
            figures[key] = surface_metrics(geometry, scene)
    if reprojection and sim is not None:
        figures["fused_reprojection"] = _fused_reprojection(ws, gt_cams, sim)
    return figures


def _fused_reprojection(ws: Path, gt_cams: dict, to_gt, max_points: int = 200_000) -> dict:
    """Reprojection error of (a sample of) the fused cloud into the ground-truth cameras, in pixels,
    after refining ``to_gt`` on the sparse model's observations (:mod:`recon.eval.reprojection`)."""
    import numpy as np
    import pycolmap
    import trimesh

    from recon.eval.reprojection import DenseView, refine_alignment, reprojection_errors
    from recon.mvs.colmap_io import read_depth_map
    from recon.stages.mesh import dense_views, scaled_to

    points = np.asarray(trimesh.load(ws / "dense" / "fused.ply").vertices)
    if len(points) > max_points:
        points = points[np.random.default_rng(0).choice(len(points), max_points, replace=False)]
    sparse = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    photos = {image.name: sparse.camera(image.camera_id) for image in sparse.images.values() if image.has_pose}
    by_base = {Path(n).name: n for n in gt_cams}
    views = []
    for view in dense_views(ws / "dense"):
        path = ws / "dense" / "stereo" / "depth_maps" / f"{view.name}.geometric.bin"
        camera = photos.get(view.name)
        if not path.exists() or camera is None or Path(view.name).name not in by_base:
            continue
        depth = read_depth_map(path)
        scaled = scaled_to(view, depth.shape[1], depth.shape[0])
        views.append(DenseView(by_base[Path(view.name).name], view.R, view.t, scaled.K, depth,
                               lambda x, cam=camera: cam.img_from_cam(x), (camera.width, camera.height)))
    observations = []
    for image in sparse.images.values():
        name = by_base.get(Path(image.name).name)
        seen = [p for p in image.points2D if p.has_point3D()] if image.has_pose and name else []
        if seen:
            cam, truth = sparse.camera(image.camera_id), gt_cams[name]
            scale = [truth.width / cam.width, truth.height / cam.height] if truth.width and truth.height else 1.0
            observations.append((name, np.array([sparse.point3D(p.point3D_id).xyz for p in seen]),
                                 np.array([p.xy for p in seen]) * scale))
    to_gt = refine_alignment(observations, gt_cams, to_gt)
    errors = reprojection_errors(points, views, gt_cams, to_gt)
    if not len(errors):
        return {}
    return {"median_px": float(np.median(errors)), "p90_px": float(np.percentile(errors, 90)),
            "observations": len(errors), "points": len(points)}


def format_eval(figures: dict) -> str:
    lines = []
    p = figures.get("poses")
    if p:
        lines.append(f"poses    registered {p['registered']}/{p['total']}   AUC@1/3/5 {p['auc@1']:.1f} / "
                     f"{p['auc@3']:.1f} / {p['auc@5']:.1f}   median camera-centre error "
                     f"{p['median_center_error']:.4g} ({100 * p['median_center_error_rel']:.3f}% of scale)")
    for key in ("fused", "mesh"):
        m = figures.get(key)
        if m:
            taus = sorted(float(k.split("@")[1]) for k in m if k.startswith("fscore@"))
            cells = "   ".join(f"@{100 * t:g}% of extent: accuracy {m[f'accuracy@{t:g}']:.1f} completeness "
                               f"{m[f'completeness@{t:g}']:.1f} F {m[f'fscore@{t:g}'] / 100:.3f}" for t in taus)
            lines.append(f"{key:<8} {cells}")
    r = figures.get("fused_reprojection")
    if r:
        lines.append(f"fused    reprojection into the ground-truth cameras: median {r['median_px']:.2f} px, "
                     f"90th percentile {r['p90_px']:.2f} px ({r['observations']} observations of "
                     f"{r['points']} points)")
    return "\n".join(lines)


def synth(out: str | Path, **kwargs) -> Path:
    from recon.synth import render_scene

    render_scene(Path(out), **kwargs)
    return Path(out)


def demo(workspace: str | Path = "demo_workspace", config: str | Path | None = None) -> dict:
    """Render the demo scene when absent, run the demo pipeline on it, evaluate against its ground truth."""
    scene = Path(workspace).absolute().parent / "demo_scene"
    if not (scene / "gt" / "scene.json").exists():
        log.info("demo: rendering the synthetic demo scene into %s", scene)
        synth(scene, views=24, width=640, height=480, seed=0)
    run(config or DEMO_CONFIG, images=str(scene / "images"), workspace=str(workspace),
        overrides={"report.gt": str(scene)})
    return evaluate(workspace, scene)


# ---------------------------------------------------------------------------------------------
# Localization of new photos in an existing reconstruction


def localize(workspace: str | Path, photos: str | Path | list[str | Path], out: str | Path | None = None, *,
             overrides: list[str] | dict | None = None, **options: Any) -> dict:
    """Place new photos in the reconstruction ``workspace`` (its ``sparse/0`` and ``database.db``).

    ``photos``: photo files (linked into ``<out>/photos/``) or one folder of photos. ``out``: the
    output workspace, by default ``<workspace>/localize``. ``options``: the ``localize`` stage's
    (e.g. ``min_inliers=20``); ``overrides``: any other config key (``{"ingest.camera_model": ...}``).
    Returns the content of ``<out>/poses.json`` with ``workspace`` (the output workspace) added;
    the extended model is ``<out>/sparse/0``.
    """
    reference = Path(workspace).absolute()
    if not reference.is_dir():
        raise WorkspaceError(f"{workspace}: no such folder; give the workspace of a finished reconstruction")
    target = Path(out).absolute() if out is not None else reference / "localize"
    config = {"images": str(_photo_folder(photos, target)), "workspace": str(target),
              "stages": ["ingest", "localize"], "ingest": {"min_photos": 1},
              "localize": {"model": str(reference), **options}}
    run(config, overrides=overrides)
    result = read_json(target / "poses.json")
    result["workspace"] = str(target)
    return result


def _photo_folder(photos: str | Path | list[str | Path], target: Path) -> Path:
    """The folder of photos to localize: ``photos`` itself when it is one folder, else a folder of
    links to the given files, kept in step with them (links to photos no longer given are removed)."""
    items = [Path(photos)] if isinstance(photos, (str, Path)) else [Path(p) for p in photos]
    if not items:
        raise ConfigError("localize: no photos given")
    if len(items) == 1 and items[0].is_dir():
        return items[0].absolute()
    for path in items:
        if not path.is_file():
            raise ConfigError(f"localize: {path} is not a photo file; give photo files, or one folder of photos")
    names = [p.name for p in items]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"localize: several photos are named {', '.join(twice)}; rename them or put them in "
                          "one folder and give the folder")
    folder = target / "photos"
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        if old.is_symlink() and old.name not in names:
            old.unlink()
    for path in items:
        link = folder / path.name
        if link.is_symlink() and link.resolve() == path.resolve():
            continue
        if link.is_symlink():
            link.unlink()
        link.symlink_to(path.resolve())
    return folder


def format_localize(result: dict) -> str:
    """Per photo: placed (inliers, camera centre) or refused (the reason); then where the outputs are."""
    width = max([len(p["name"]) for p in result["photos"]] + [4])
    lines = []
    for p in result["photos"]:
        if p["placed"]:
            centre = ", ".join(f"{v:.4g}" for v in p["centre"])
            lines.append(f"placed   {p['name']:<{width}}  {p['inliers']} inliers of {p['matches']} matches   "
                         f"centre ({centre})")
        else:
            lines.append(f"refused  {p['name']:<{width}}  {p['reason']}")
    ws = Path(result["workspace"])
    lines.append(f"recon: placed {result['placed']} of {result['total']} photo(s); poses in {ws / 'poses.json'}, "
                 f"model with them in {ws / 'sparse' / '0'}")
    return "\n".join(lines)
