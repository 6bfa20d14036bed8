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
from recon.files import read_json
from recon.workspace import CACHE_DIR, Workspace, WorkspaceError

log = logging.getLogger("recon")

#: the ready configs ship inside the package (``pipelines/`` in a checkout links to them)
DEMO_CONFIG = Path(__file__).resolve().parent / "pipelines" / "demo.yaml"


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
    from recon.logs import quiet_colmap

    quiet_colmap(ws.meta / "logs" / "colmap.")
    return pipeline.run(cfg, from_stage=from_stage, until=until, force=force, verify=verify)


def _yaml(value: Any) -> str:
    import yaml

    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()


def _config_for(target: str | Path | dict, overrides=None, images=None, workspace=None) -> pipeline.RunConfig:
    if isinstance(target, dict):
        return load(target, overrides, images=images, workspace=workspace)
    path = Path(target)
    if path.is_dir():
        saved = Workspace(path).saved_config()
        if saved is None:
            raise WorkspaceError(f"{path}: not a recon workspace (no run recorded in {CACHE_DIR}/); pass the "
                                 "config file")
        base, data = saved
        data["workspace"] = str(path.absolute())
        cfg = load(data, overrides, images=images)
        return pipeline.RunConfig(cfg.run, cfg.stages, Path(base))
    return load(path, overrides, images=images, workspace=workspace)


def status(target: str | Path | dict, overrides=None, images=None, workspace=None,
           verify: bool = False) -> list[pipeline.StageStatus]:
    return pipeline.status(_config_for(target, overrides, images, workspace), verify=verify)


def clean(target: str | Path, everything: bool = False, workspace: str | None = None) -> tuple[int, int]:
    path = Path(target)
    if path.is_dir():
        cfg = _config_for(path) if Workspace(path).saved_config() is not None else None
        return pipeline.clean(cfg, path, everything)
    cfg = _config_for(path, workspace=workspace)
    return pipeline.clean(cfg, cfg.workspace, everything)


# ---------------------------------------------------------------------------------------------
# Evaluation, synthetic scenes, demo


def evaluate(workspace: str | Path, gt: str | Path) -> dict:
    """Figures of a workspace against ground truth (:func:`recon.eval.workspace.evaluate`)."""
    from recon.eval.workspace import EvaluationError
    from recon.eval.workspace import evaluate as evaluate_workspace

    try:
        return evaluate_workspace(Path(workspace), Path(gt))
    except EvaluationError as exc:
        raise ConfigError(f"--gt {exc}" if str(exc).startswith(str(gt)) else str(exc)) from None


def model_to_ground_truth(workspace: str | Path, gt: str | Path):
    """The similarity taking the model's world to the ground truth's (robust fit on camera centres)."""
    from recon.eval.workspace import EvaluationError, model_to_ground_truth

    try:
        return model_to_ground_truth(Path(workspace), Path(gt))
    except EvaluationError as exc:
        raise ConfigError(f"--gt {exc}" if str(exc).startswith(str(gt)) else str(exc)) from None


def synth(out: str | Path, scene: str | None = None, camera: str = "pinhole", **kwargs) -> Path:
    """Render the seeded synthetic scene (recon.synth.render_scene) or, with ``scene``, a zoo scene
    (recon.synth.zoo.render_zoo) into ``out``; ``camera`` fisheye or 360: recon.synth.wide's fisheye
    orbit or room walk. Keyword arguments given as None take their defaults."""
    options = {k: v for k, v in kwargs.items() if v is not None}
    if camera != "pinhole":
        from recon.synth.wide import render_fisheye_orbit, render_room_walk

        if scene is not None or options.get("holdout"):
            raise ConfigError(f"--camera {camera}: renders its own scene without hold-out views; leave out "
                              "--scene and --holdout")
        options.pop("holdout", None)
        if camera == "360" and options.get("width", 1536) != 2 * options.get("height", 768):
            raise ConfigError("--width/--height: a 360 panorama is twice as wide as high (e.g. 1536 x 768)")
        (render_fisheye_orbit if camera == "fisheye" else render_room_walk)(Path(out), **options)
    elif scene is None:
        from recon.synth import render_scene

        render_scene(Path(out), **options)
    else:
        from recon.synth.zoo import UnknownScene, render_zoo

        try:
            render_zoo(scene, Path(out), **options)
        except UnknownScene as exc:
            raise ConfigError(f"--scene: {exc}") from None
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
