"""export: the largest sparse model as COLMAP text, a coloured points.ply and nerfstudio's transforms.json."""

from __future__ import annotations

from dataclasses import dataclass

from recon.files import write_json
from recon.options import opt
from recon.products import Exports, SparseModel
from recon.sparse.export import transforms_json, write_points_ply
from recon.stage import Stage, StageContext, register


@dataclass(frozen=True)
class ExportConfig:
    colmap_text: bool = opt(True, "also write the model as COLMAP text files (sparse_text/)")
    transforms: bool = opt(True, "write nerfstudio's transforms.json (image paths relative to the workspace)")
    points: bool = opt(True, "write the sparse points with colours as points.ply")


@register
class Export(Stage):
    name = "export"
    version = 2
    Config = ExportConfig
    requires = (SparseModel,)
    produces = Exports
    summary = "COLMAP text model, coloured points.ply, nerfstudio transforms.json"

    def run(self, ctx: StageContext, cfg: ExportConfig) -> dict:
        import pycolmap

        rec = pycolmap.Reconstruction(str(ctx.input(SparseModel).model()))
        summary = {"registered": rec.num_reg_images()}
        if cfg.colmap_text:
            ctx.output.text_model.mkdir(exist_ok=True)
            rec.write_text(str(ctx.output.text_model))
            spaced = [img.name for img in rec.images.values() if any(c.isspace() for c in img.name)]
            if spaced:  # COLMAP's text reader splits lines at spaces
                ctx.log.warning("sparse_text: %d photo names hold spaces (e.g. '%s'), which COLMAP's text format "
                                "cannot represent: read the binary model sparse/0 instead", len(spaced), spaced[0])
        if cfg.points:
            summary["points"] = write_points_ply(rec, ctx.output.points)
        if cfg.transforms:
            # points.ply sits beside transforms.json, in the output folder and in the workspace
            points_file = ctx.output.points.name if cfg.points else None
            write_json(ctx.output.transforms, transforms_json(rec, points_file=points_file))
        return summary
