"""report: report.html, one self-contained page with the run's figures, plots and a 3D viewer.

It needs the sparse stages; dense depth maps, the fused cloud, the mesh and the textured model are
shown when the workspace has them from stages consistent with this run's sparse model (a dense
output built on an older sparse model is left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from recon.options import opt
from recon.products import (
    DenseScene,
    DepthMaps,
    FusedCloud,
    MatchDatabase,
    SparseModel,
    SurfaceMesh,
    TexturedModel,
)
from recon.products import Report as ReportProduct
from recon.stage import REGISTRY, Stage, StageContext, StageError, producer, register

#: (Sources field, product, its file) the report shows when a current stage made them; a later entry
#: wins (texture's vertex-coloured mesh.ply over mesh's)
OPTIONAL = [("stereo", DepthMaps, lambda p: p.folder), ("fused", FusedCloud, lambda p: p.path),
            ("mesh", SurfaceMesh, lambda p: p.path), ("textured", TexturedModel, lambda p: p.glb),
            ("mesh", TexturedModel, lambda p: p.mesh)]


@dataclass(frozen=True)
class ReportConfig:
    gt: str | None = opt(None, "ground truth for evaluation figures: a dataset folder, *_par.txt, Strecha folder, "
                               "transforms.json or a synthetic scene; relative to the config file")
    viewer: bool = opt(True, "include the 3D viewer (adds ~0.8 MB of three.js to the page)")
    max_points: int = opt(100_000, "most sparse / dense points in the viewer (a random subset beyond)", ge=1000)
    max_mesh_faces: int = opt(300_000, "largest mesh.ply (faces) shown in the viewer when there is no "
                                       "textured.glb", ge=0)
    max_glb_mb: float = opt(4.0, "largest textured.glb embedded in the viewer as it is, MB; a larger one is shown "
                                 "as a copy made for the page (model_faces, model_texture)", ge=0)
    model_faces: int = opt(30_000, "faces of the page's copy of a large textured.glb (decimated)", ge=100)
    model_texture: int = opt(2048, "largest texture side of that copy, texels", ge=64, le=8192)
    thumbnails: int = opt(12, "depth / normal map thumbnails shown", ge=0)


@register
class Report(Stage):
    name = "report"
    version = 4
    Config = ReportConfig
    requires = (MatchDatabase, SparseModel)
    optional = (DenseScene, DepthMaps, FusedCloud, SurfaceMesh, TexturedModel)
    produces = ReportProduct
    summary = "report.html: run summary, per-photo table, plots, depth maps, mesh figures, 3D viewer"

    def fingerprint(self, ctx: StageContext, cfg: ReportConfig):
        """The optional outputs the report will show that this run does not make: the stages (and keys)
        that produced them. Those this run plans are in the key already as upstream stages; counted
        again here, they were absent when a first full run was planned and present at the next, so
        an unchanged second run made the report again."""
        return {stage: key for stage, key, _ in _current_optional(ctx.workspace) if stage not in ctx.upstream}

    def run(self, ctx: StageContext, cfg: ReportConfig) -> dict:
        from recon.report import Limits, Sources, build_report

        ws = ctx.workspace
        optional = {attr: path for _, _, (attr, path) in _current_optional(ws)}
        lock = ws.meta / "lock"
        sparse = ctx.input(SparseModel)
        sources = Sources(
            database=ctx.input(MatchDatabase).database,
            model=sparse.model(),
            models_json=sparse.root / sparse.REPORT,
            georeference=sparse.georeference,
            stages=[m for m in (ws.manifest(n, k) for n, k in _current_stages(ws) if n != self.name) if m],
            run_started=lock.stat().st_mtime if lock.exists() else None,
            config=ctx.settings,
            **optional)
        evaluation = _evaluate(ctx, cfg) if cfg.gt else None
        limits = Limits(max_points=cfg.max_points, max_mesh_faces=cfg.max_mesh_faces,
                        max_glb_bytes=int(cfg.max_glb_mb * 1e6), model_faces=cfg.model_faces,
                        model_texture=cfg.model_texture, thumbnails=cfg.thumbnails, viewer=cfg.viewer)
        report = build_report(sources, title=f"recon report: {ws.root.name}", evaluation=evaluation, limits=limits)
        ctx.output.path.write_text(report.html, encoding="utf-8")
        ctx.log.info("report: %s (%.1f MB)", ws.root / ReportProduct.publish["report.html"], len(report.html) / 1e6)
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
    current = dict(_current_stages(ws))
    found = []
    for attr, product, file in OPTIONAL:
        name = producer(product)
        if name in current:
            path = file(product(ws.output_dir(name, current[name])))
            if path.exists():
                found.append((name, current[name], (attr, path)))
    return found


def _evaluate(ctx: StageContext, cfg: ReportConfig) -> dict:
    from recon.eval.workspace import EvaluationError, evaluate

    gt = ctx.resolve(cfg.gt)
    try:
        return evaluate(ctx.workspace.root, gt)
    except (EvaluationError, FileNotFoundError) as exc:
        raise StageError(f"report.gt: cannot evaluate against {gt}: {exc}") from None
