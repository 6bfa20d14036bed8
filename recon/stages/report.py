"""report: report.html, one self-contained page with the run's figures, plots and a 3D viewer.

It needs the sparse stages; dense depth maps, the fused cloud, the mesh and the textured model are
shown when the workspace has them from stages consistent with this run's sparse model (a dense
output built on an older sparse model is left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from recon.options import opt
from recon.stage import REGISTRY, Stage, StageContext, StageError, register

#: workspace paths the report shows when a current stage published them
OPTIONAL = {"stereo": "dense/stereo", "fused": "dense/fused.ply", "mesh": "mesh.ply", "textured": "textured.glb"}


@dataclass(frozen=True)
class ReportConfig:
    gt: str | None = opt(None, "ground truth for evaluation figures: a dataset folder, *_par.txt, Strecha folder, "
                               "transforms.json or a synthetic scene; relative to the config file")
    viewer: bool = opt(True, "include the 3D viewer (adds ~0.8 MB of three.js to the page)")
    max_points: int = opt(200_000, "most sparse / dense points in the viewer (a random subset beyond)", ge=1000)
    max_mesh_faces: int = opt(300_000, "largest mesh.ply (faces) shown in the viewer when there is no "
                                       "textured.glb", ge=0)
    max_glb_mb: float = opt(20.0, "largest textured.glb embedded in the viewer, MB", ge=0)
    thumbnails: int = opt(12, "depth / normal map thumbnails shown", ge=0)


@register
class Report(Stage):
    name = "report"
    version = 1
    Config = ReportConfig
    requires = ("matching", "sfm")
    optional = ("undistort", "mvs", "fusion", "mesh", "texture")
    outputs = ("report.html",)
    publish = {"report.html": "report.html"}
    summary = "report.html: run summary, per-photo table, plots, depth maps, mesh figures, 3D viewer"

    def fingerprint(self, ctx: StageContext, cfg: ReportConfig):
        """The optional outputs the report will show: the stages (and keys) that produced them."""
        return {stage: key for stage, key, _ in _current_optional(ctx.workspace)}

    def run(self, ctx: StageContext, cfg: ReportConfig) -> dict:
        from recon.report import Limits, Sources, build_report

        ws = ctx.workspace
        optional = {attr: path for _, _, (attr, path) in _current_optional(ws)}
        lock = ws.meta / "lock"
        sources = Sources(
            database=ctx.input("matching") / "database.db",
            model=ctx.input("sfm") / "sparse" / "0",
            models_json=ctx.input("sfm") / "models.json",
            stages=[m for m in (ws.manifest(n, k) for n, k in _current_stages(ws) if n != self.name) if m],
            run_started=lock.stat().st_mtime if lock.exists() else None,
            config=ctx.settings,
            **optional)
        evaluation = _evaluate(ctx, cfg) if cfg.gt else None
        limits = Limits(max_points=cfg.max_points, max_mesh_faces=cfg.max_mesh_faces,
                        max_glb_bytes=int(cfg.max_glb_mb * 1e6), thumbnails=cfg.thumbnails, viewer=cfg.viewer)
        report = build_report(sources, title=f"recon report: {ws.root.name}", evaluation=evaluation, limits=limits)
        (ctx.out / "report.html").write_text(report.html, encoding="utf-8")
        ctx.log.info("report: %s (%.1f MB)", ws.root / "report.html", len(report.html) / 1e6)
        return {**report.summary, "megabytes": round(len(report.html) / 1e6, 2)}


def _current_stages(ws) -> list[tuple[str, str]]:
    """(stage, key) of each completed stage in the workspace state whose inputs are the current outputs
    of the stages it read, in pipeline order: what the workspace's links show now."""
    state = ws.state()
    manifests = {name: ws.manifest(name, key) for name, key in state.items() if name in REGISTRY}
    memo: dict[str, bool] = {}

    def current(name: str) -> bool:
        if name not in memo:
            m = manifests.get(name)
            memo[name] = m is not None and all(state.get(dep) == key and current(dep)
                                                for dep, key in m.get("upstream", {}).items())
        return memo[name]

    return [(name, state[name]) for name in REGISTRY if name in state and current(name)]


def _current_optional(ws) -> list[tuple[str, str, tuple[str, Path]]]:
    """(stage, key, (Sources field, path in its output)) for each optional output a current stage made."""
    found = []
    for name, key in _current_stages(ws):
        for rel, link in REGISTRY[name].publish.items():
            for attr, wanted in OPTIONAL.items():
                path = ws.output_dir(name, key) / rel
                if link == wanted and path.exists():
                    found.append((name, key, (attr, path)))
    return found


def _evaluate(ctx: StageContext, cfg: ReportConfig) -> dict:
    from recon import api
    from recon.config import ConfigError
    from recon.workspace import WorkspaceError

    gt = ctx.resolve(cfg.gt)
    try:
        return api.evaluate(ctx.workspace.root, gt)
    except (ConfigError, WorkspaceError, FileNotFoundError, ValueError) as exc:
        raise StageError(f"report.gt: cannot evaluate against {gt}: {exc}") from None
