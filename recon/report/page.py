"""The report page: one self-contained HTML file (inline CSS and JavaScript, figures as data: URIs,
three.js inlined) that opens offline from the file system."""

from __future__ import annotations

import base64
import html
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon import __version__
from recon.report import gather, plots, preview
from recon.report import viewer as viewer_data

PACKAGE = Path(__file__).resolve().parent
TEMPLATES = PACKAGE / "templates"
THREE = PACKAGE / "vendor" / "three.bundle.min.js"


@dataclass(frozen=True)
class Limits:
    """How much of a large run goes into the page."""

    max_points: int = 100_000        # sparse / dense points in the viewer (random subset)
    max_mesh_faces: int = 300_000    # mesh.ply embedded in the viewer when no textured.glb
    max_glb_bytes: int = 4_000_000   # textured.glb embedded as it is; a larger one as a copy made for the page
    model_faces: int = 30_000        # faces of that copy
    model_texture: int = 2048        # its texture's largest side, texels
    thumbnails: int = 12             # depth / normal map thumbnails
    viewer: bool = True              # include the 3D viewer (three.js: ~0.8 MB)


#: what the page's mean reprojection error is (the one the sfm stage logs and records in its summary)
REPROJECTION_DEFINITION = ("Mean reprojection error: the mean over the sparse points of each point's mean "
                           "reprojection error in the photos that see it (COLMAP's definition, the figure the sfm "
                           "stage logs). The per-photo column is the mean over that photo's observations.")


@dataclass
class Report:
    html: str
    summary: dict  # counts for the stage manifest


def build_report(sources: gather.Sources, *, title: str, evaluation: dict | None = None,
                 limits: Limits = Limits()) -> Report:
    """Read what ``sources`` has, draw the figures and return the page."""
    summary: dict = {"plots": 0}
    sections: list[tuple[str, str, str]] = []  # (anchor, heading, html)
    registration = _read_json(sources.models_json)
    matches = gather.read_matches(sources.database) if _exists(sources.database) else None
    model, per_image = (gather.read_model(sources.model) if _exists(sources.model) else (None, {}))
    rows = gather.image_rows(matches, registration, per_image) if matches is not None else []

    def figure(png: bytes, name: str, caption: str, cls: str = "plot") -> str:
        summary["plots"] += 1
        return (f'<figure><img class="{cls}" data-plot="{_e(name)}" alt="{_e(caption)}" '
                f'src="{_data_uri(png)}"><figcaption>{_e(caption)}</figcaption></figure>')

    dense = None
    if _exists(sources.fused):
        total, xyz, rgb = gather.read_point_cloud(sources.fused, limits.max_points)
        dense = (xyz, rgb)
        summary["dense_points"] = total
    glb = sources.textured.read_bytes() if _exists(sources.textured) and limits.viewer else None
    glb_note = ""
    if glb is not None and len(glb) > limits.max_glb_bytes:
        size = len(glb)
        glb = preview.page_model(glb, limits.model_faces, limits.model_texture)
        glb_note = (f"textured.glb ({size / 1e6:.1f} MB) is shown as a copy made for this page ({len(glb) / 1e6:.1f} "
                    f"MB: at most {limits.model_faces} faces, a texture of at most {limits.model_texture} texels a "
                    "side): open textured.glb in Blender or any glTF viewer for the full model.")
        summary["page_model_mb"] = round(len(glb) / 1e6, 2)

    if limits.viewer:
        data = viewer_data.payload(model, dense, sources.mesh if _exists(sources.mesh) else None,
                                   limits.max_mesh_faces, glb, limits.max_points)
        sections.append(("viewer", "3D view", _viewer_section(glb_note)))
    run = _run_section(sources)
    if run:
        sections.append(("run", "Run", run))
    if rows:
        sections.append(("photos", "Photos", _photos_section(rows, figure)))
    if matches is not None and len(matches.names) > 1:
        sections.append(("matching", "Matching", figure(plots.pair_matrix(matches.pairs, matches.names),
                                                        "pair-matrix", "Verified matches of every photo pair")))
    if model is not None:
        sections.append(("sparse-model", "Sparse model", _sparse_section(model, registration, figure)))
        summary["registered"] = len(model.names)
        summary["points"] = len(model.points)
    georef = _read_json(sources.georeference)
    if georef:
        sections.append(("georeference", "Scale and position", _georef_section(georef, model, figure)))
        summary["scale_source"] = georef.get("scale_source", "none")
    if _exists(sources.stereo):
        count, views = gather.dense_views(sources.stereo, limits.thumbnails)
        if count:
            sections.append(("dense", "Depth and normal maps", _dense_section(count, views, figure)))
            summary["depth_maps"] = count
    if _exists(sources.mesh):
        stats = gather.mesh_statistics(sources.mesh)
        sections.append(("mesh", "Mesh", _table([(k, _fmt(v)) for k, v in stats.items()])))
        summary["mesh_faces"] = stats["faces"]
    if evaluation:
        sections.append(("evaluation", "Evaluation against ground truth", _evaluation_section(evaluation, figure)))
    summary["images"] = len(rows)

    header = (f"<header><h1>{_e(title)}</h1><p>{_e(_headline(rows, model))} · written "
              f"{time.strftime('%Y-%m-%d %H:%M')}</p></header>")
    nav = "<nav>" + "".join(f'<a href="#{a}">{_e(h)}</a>' for a, h, _ in sections) + "</nav>"
    body = header + nav + "<main>" + "".join(
        f'<section id="{a}"><h2>{_e(h)}</h2>{content}</section>' for a, h, content in sections) + "</main>"
    scripts = ""
    if limits.viewer:
        scripts = (f'<script id="viewer-data" type="application/json">{_json_for_script(data)}</script>\n'
                   f"<script>{THREE.read_text()}</script>\n<script>{(TEMPLATES / 'viewer.js').read_text()}</script>")
    page = (TEMPLATES / "report.html").read_text()
    for key, value in (("{{title}}", _e(title)), ("{{version}}", __version__),
                       ("{{css}}", (TEMPLATES / "report.css").read_text()), ("{{body}}", body),
                       ("{{scripts}}", scripts)):
        page = page.replace(key, value, 1)
    return Report(page, summary)


# ---------------------------------------------------------------------------------------------
# Sections


def _viewer_section(note: str) -> str:
    return ('<div id="viewer" data-state="loading"><div class="layers"></div><div class="canvas-holder"></div>'
            '<p id="viewer-status" class="muted">Drag to orbit, right-drag to pan, scroll to zoom.</p>'
            + (f'<p class="muted">{_e(note)}</p>' if note else "") + "</div>")


def _run_section(sources: gather.Sources) -> str:
    stage_rows = gather.stage_rows(sources)
    out = []
    if stage_rows:
        total = sum(r.seconds for r in stage_rows if r.ran)
        rows = []
        for r in stage_rows:
            state = "—" if r.ran is None else ("ran" if r.ran else "cached")
            facts = ", ".join(f"{k}={_fmt(v)}" for k, v in r.summary.items() if not isinstance(v, (dict, list)))
            rows.append(f"<tr><td>{_e(r.name)}</td><td>{state}</td><td class=num>{r.seconds:.1f} s</td>"
                        f"<td>{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(r.finished))}</td>"
                        f"<td><code>{_e(r.key[:12])}</code></td><td>{_e(facts)}</td></tr>")
        out.append("<table><tr><th>stage</th><th>this run</th><th class=num>time</th><th>finished</th>"
                   "<th>cache key</th><th>summary</th></tr>" + "".join(rows) + "</table>")
        if any(r.ran is not None for r in stage_rows):
            out.append(f'<p class="muted">Stages that ran in this run took {total:.1f} s; cached stages were '
                       "reused from an earlier run with the same inputs and options.</p>")
    versions = sources.stages[-1].get("versions", {}) if sources.stages else {}
    if versions:
        out.append("<h3>Versions</h3>" + _table(sorted(versions.items())))
    if sources.config:
        import yaml

        out.append("<details><summary>Configuration</summary><pre>"
                   + _e(yaml.safe_dump(sources.config, sort_keys=False, default_flow_style=False))
                   + "</pre></details>")
    return "".join(out)


def _photos_section(rows: list[gather.ImageRow], figure) -> str:
    bad = [r for r in rows if not r.registered]
    out = [f'<div class="kpis">{_kpi(f"{len(rows) - len(bad)} / {len(rows)}", "photos registered")}'
           f'{_kpi(str(int(np.median([r.keypoints for r in rows]))), "median keypoints")}</div>']
    if bad:
        out.append(f'<h3 class="bad">{len(bad)} photo(s) not registered</h3><ul id="unregistered">'
                   + "".join(f"<li><b>{_e(r.name)}</b>: {_e(r.reason)}</li>" for r in bad) + "</ul>")
    out.append(figure(plots.per_image([r.name for r in rows], [r.keypoints for r in rows],
                                      [r.verified_matches for r in rows], [r.reproj_error for r in rows],
                                      [r.registered for r in rows]),
                      "per-image", "Keypoints, verified matches and reprojection error per photo", "wide"))
    head = ("<tr><th>photo</th><th>registered</th><th class=num>size</th><th class=num>keypoints</th>"
            "<th class=num>matched photos</th><th class=num>verified matches</th><th class=num>3D points seen</th>"
            "<th class=num>mean reproj. error (px)</th><th>why not registered</th></tr>")
    body = []
    for r in rows:
        body.append(
            f'<tr class="{"registered" if r.registered else "unregistered"}" data-image="{_e(r.name)}">'
            f"<td>{_e(r.name)}</td><td>{'yes' if r.registered else '<span class=bad>no</span>'}</td>"
            f"<td class=num>{r.width}×{r.height}</td><td class=num>{r.keypoints}</td>"
            f"<td class=num>{r.matched_images}</td><td class=num>{r.verified_matches}</td>"
            f"<td class=num>{r.observations if r.registered else ''}</td>"
            f"<td class=num>{'' if r.reproj_error is None else f'{r.reproj_error:.3f}'}</td>"
            f"<td>{_e(r.reason)}</td></tr>")
    out.append('<div class="scroll"><table id="images">' + head + "".join(body) + "</table></div>")
    return "".join(out)


def _sparse_section(model: gather.Model, registration: dict, figure) -> str:
    models = registration.get("models", [])
    kpis = [_kpi(str(len(model.names)), "cameras"), _kpi(str(len(model.points)), "points"),
            _kpi(f"{model.mean_error:.3f} px" if len(model.point_errors) else "—", "mean reprojection error"),
            _kpi(f"{model.track_lengths.mean():.2f}" if len(model.track_lengths) else "—", "mean track length")]
    if len(models) > 1:
        kpis.append(_kpi(str(len(models)), "separate models (largest shown)"))
    up = model.up
    a = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 0.3:
        a = np.cross(up, [0.0, 1.0, 0.0])
    cloud = model.points if len(model.points) else model.centers
    centred = cloud - cloud.mean(axis=0)
    flat = centred - np.outer(centred @ up, up)
    if len(flat) >= 2:  # main horizontal direction of the scene: its largest spread across up
        a = np.linalg.svd(flat, full_matrices=False)[2][0]
    a = a / np.linalg.norm(a)
    b = np.cross(up, a)
    directions = model.rotations[:, 2, :]  # viewing directions (camera z axes) in the world
    points, colors = model.points, model.colors
    if len(points) > 60_000:
        keep = np.random.default_rng(0).choice(len(points), 60_000, replace=False)
        points, colors = points[keep], colors[keep]
    top = plots.scene_view(points, colors, model.centers, directions, np.array([a, b]), "Top view",
                           ("horizontal axis 1", "horizontal axis 2"))
    side = plots.scene_view(points, colors, model.centers, directions, np.array([a, up]), "Side view",
                            ("horizontal axis 1", "up"))
    return (_mapper_note(registration) + f'<div class="kpis">{"".join(kpis)}</div>'
            '<p class="muted" id="reprojection-definition">'
            f'{_e(REPROJECTION_DEFINITION)}</p><div class="plots">'
            + figure(plots.track_lengths(model.track_lengths), "track-lengths", "Track length histogram")
            + figure(plots.reprojection_errors(model.point_errors, model.mean_error), "reprojection-errors",
                     "Reprojection error of the sparse points")
            + figure(top, "top-view", "Cameras and points seen from above (up = the photos' average up)")
            + figure(side, "side-view", "Cameras and points seen from the side")
            + "</div>")


def _georef_section(georef: dict, model: gather.Model | None, figure) -> str:
    """What fixed the model's scale and position (georeference.json), with the residuals of the GPS
    photos, GCPs and scale bars, and a map of the photos when the model is in East-North-Up metres."""
    source = georef.get("scale_source", "none")
    kpis = [_kpi(source, "scale from")]
    if georef.get("scale_relative_std") is not None:
        kpis.append(_kpi(f"{100 * georef['scale_relative_std']:.2g} %", "scale uncertainty (1 sigma)"))
    origin = georef.get("origin")
    if georef.get("georeferenced") and origin:
        kpis.append(_kpi(f"{origin['lat']:.6f}, {origin['lon']:.6f}", "origin (lat, lon)"))
    residuals = georef.get("residuals_m")
    if residuals:
        kpis.append(_kpi(f"{residuals['median']:.2f} m / {residuals['p90']:.2f} m", "GPS residuals median / p90"))
    gcp = georef.get("gcp")
    if gcp:
        kpis.append(_kpi(f"{gcp['rms_m']:.3f} m", "GCP residual RMS"))
        if gcp.get("check_rms_m") is not None:
            kpis.append(_kpi(f"{gcp['check_rms_m']:.3f} m", "GCP leave-one-out check RMS"))
    out = [f'<div class="kpis">{"".join(kpis)}</div>']
    out.append(f'<p class="muted">Frame: {_e(georef.get("crs") or "as the mapper left it, up along +Z")}.'
               + (f" Not georeferenced: {_e(georef['reason'])}." if georef.get("reason") else "") + "</p>")
    prior = georef.get("gps_prior")
    if prior:
        out.append('<p id="gps-prior">GPS prior bundle adjustment: '
                   + (f"done with {prior['photos']} photos ({_e(prior['why'])}); mean reprojection error "
                      f"{prior['reprojection_error_px']['before']:.3f} -> {prior['reprojection_error_px']['after']:.3f} px"
                      if prior["used"] else f"not done: {_e(prior['why'])}") + ".</p>")
    photos = georef.get("photos") or []
    if georef.get("georeferenced") and model is not None:
        out.append('<div class="plots">' + figure(plots.enu_map(model.centers, photos, (gcp or {}).get("points", [])),
                                                  "enu-map", "Photos and control points on a map (ENU metres)")
                   + "</div>")
    if gcp:
        rows = "".join(
            f"<tr><td>{_e(g['name'])}</td><td>{'yes' if g['inlier'] else '<span class=bad>no: outlier</span>'}</td>"
            f"<td class=num>{g['residual_m']:.3f}</td><td class=num>"
            + " ".join(f"{v:+.3f}" for v in g["residual_enu"]) + "</td><td class=num>"
            + ("—" if g["check_m"] is None else f"{g['check_m']:.3f}") + f"</td><td class=num>{len(g['photos'])}"
            f"</td><td class=num>{g['reprojection_px']:.2f}</td></tr>" for g in gcp["points"])
        out.append('<h3>Ground control points</h3><table id="gcps"><tr><th>GCP</th><th>used</th>'
                   "<th class=num>residual (m)</th><th class=num>east north up (m)</th><th class=num>check (m)</th>"
                   "<th class=num>photos</th><th class=num>max reproj. (px)</th></tr>" + rows + "</table>"
                   f'<p class="muted">{_e(gcp["what"])}.</p>')
        if gcp["not_used"]:
            out.append("<ul>" + "".join(f"<li><b>{_e(n)}</b> not used: {_e(why)}</li>"
                                        for n, why in gcp["not_used"].items()) + "</ul>")
    if georef.get("scale_bars"):
        rows = "".join(f"<tr><td>{k}</td><td class=num>{b['length_m']:.4g}</td><td class=num>{b['model_length_m']:.4g}"
                       f"</td><td class=num>{b['error_m']:+.4f}</td><td class=num>{b['reprojection_px']:.2f}</td></tr>"
                       for k, b in enumerate(georef["scale_bars"], start=1))
        out.append('<h3>Scale bars</h3><table id="scale-bars"><tr><th>bar</th><th class=num>length (m)</th>'
                   "<th class=num>in the model (m)</th><th class=num>difference (m)</th>"
                   "<th class=num>max reproj. (px)</th></tr>" + rows + "</table>")
    for record in georef.get("markers", []):
        out.append(_markers_table(record))
    if photos:
        rows = "".join(f"<tr><td>{_e(p['name'])}</td><td class=num>{p['sigma_m']:.3g}</td>"
                       f"<td class=num>{p['residual_m']:.2f}</td>"
                       f"<td>{'yes' if p['inlier'] else '<span class=bad>no: outlier</span>'}</td></tr>" for p in photos)
        out.append('<h3>GPS residuals per photo</h3><div class="scroll"><table id="gps-photos"><tr><th>photo</th>'
                   "<th class=num>GPS sigma (m)</th><th class=num>camera to GPS (m)</th><th>used</th></tr>"
                   + rows + "</table></div>")
    return "".join(out)


def _markers_table(record: dict) -> str:
    """The printed targets of one kind (georeference.json's ``markers``): what they did, and per target
    the RMS residual of its known distances."""
    head = f'<h3>{_e(record["source"][:1].upper() + record["source"][1:])}</h3><p>{_e(record["what"])}: '
    if not record["used"]:
        return head + f'<span class=bad>not used</span>: {_e(record["reason"])}.</p>'
    std = record["scale_relative_std"]
    spread = "" if std is None else f" (+- {100 * std:.2g} %)"
    head += (f"they set the scale, x{record['scale']:.5g}{spread}" if record["set_scale"] else
             f"a check of the scale: they measure it x{record['scale']:.5g}{spread}")
    head += (f"; {record['edges']} known distances; detections in {record['photos_with_detections']} of "
             f"{record['photos_searched']} photos.</p>")
    rows = "".join(f"<tr><td>{_e(t['name'])}</td><td class=num>{len(t['length_m'])}</td><td class=num>"
                   f"{t['residual_m']:.4f}</td><td class=num>{len(t['photos'])}</td><td class=num>"
                   f"{t['reprojection_px']:.2f}</td></tr>" for t in record["targets"])
    skipped = "".join(f"<li><b>{_e(n)}</b> not used: {_e(why)}</li>" for n, why in record["not_used"].items())
    return (head + '<table class="markers"><tr><th>target</th><th class=num>distances</th><th class=num>'
            "RMS residual (m)</th><th class=num>photos</th><th class=num>max reproj. (px)</th></tr>" + rows
            + "</table>" + (f"<ul>{skipped}</ul>" if skipped else ""))


def _mapper_note(registration: dict) -> str:
    """Which mapper made the model and why (the sfm fallback) and the verified pairs it left out as
    false; the warnings of a model that leaves out more than a quarter of the photos and of one whose
    photos are tied together by few points."""
    out = ""
    if registration.get("warning"):
        out += f'<p class="bad" id="sfm-warning">{_e(registration["warning"])}</p>'
    loose = registration.get("weak_joins", {}).get("warning")
    if loose:
        out += f'<p class="bad" id="weak-joins">{_e(loose[0].upper() + loose[1:])}.</p>'
    mapper = registration.get("mapper")
    if mapper:
        out += f'<p id="mapper">Made by the {_e(mapper["used"])} mapper: {_e(mapper["why"])}.</p>'
        if mapper.get("false_pairs"):
            out += (f'<p id="false-pairs">Verified pairs its first model contradicted, left out as false matches '
                    f'before mapping again: {_e(", ".join(mapper["false_pairs"]))}.</p>')
    return out


def _dense_section(count: int, views: list[gather.DenseView], figure) -> str:
    cells = []
    for v in views:
        parts = []
        if v.depth is not None:
            valid = float((v.depth > 0).mean())
            parts.append(figure(plots.depth_thumbnail(v.depth), f"depth:{v.name}",
                                f"{v.name}: depth, {valid:.0%} of pixels", "thumb"))
        if v.normal is not None:
            parts.append(figure(plots.normal_thumbnail(v.normal), f"normal:{v.name}", f"{v.name}: normals",
                                "thumb"))
        cells.append("<div>" + "".join(parts) + "</div>")
    return (f'<p>{count} depth maps; {len(views)} shown (near = blue, far = red; black = no depth).</p>'
            f'<div class="thumbs">{"".join(cells)}</div>')


def _evaluation_section(evaluation: dict, figure) -> str:
    out = []
    poses = evaluation.get("poses")
    if poses:
        out.append(_table([(k, _fmt(v)) for k, v in poses.items()]))
        out.append('<div class="plots">' + figure(plots.pose_figures(poses), "pose-auc", "Pose accuracy") + "</div>")
    for key, what in (("fused", "Fused cloud"), ("mesh", "Mesh")):
        if evaluation.get(key):
            out.append(f'<h3>{what} against the true surface</h3><div id="{key}-surface">'
                       + _table([(k, _fmt(v)) for k, v in evaluation[key].items()]) + "</div>")
    r = evaluation.get("fused_reprojection")
    if r:
        out.append('<h3>Fused cloud reprojected into the ground-truth cameras</h3><div id="fused-reprojection">'
                   + _table([("median", f"{r['median_px']:.2f} px"), ("90th percentile", f"{r['p90_px']:.2f} px"),
                             ("observations", r["observations"]), ("points", r["points"])]) + "</div>")
    return "".join(out)


# ---------------------------------------------------------------------------------------------
# Small helpers


def _headline(rows: list[gather.ImageRow], model: gather.Model | None) -> str:
    if not rows:
        return "no photos matched yet"
    registered = sum(r.registered for r in rows)
    points = f", {len(model.points)} sparse points" if model is not None else ""
    return f"{registered} of {len(rows)} photos registered{points}"


def _kpi(value: str, label: str) -> str:
    return f'<div class="kpi"><b>{_e(value)}</b><span>{_e(label)}</span></div>'


def _table(pairs) -> str:
    return "<table>" + "".join(f"<tr><th>{_e(str(k))}</th><td>{_e(str(v))}</td></tr>" for k, v in pairs) + "</table>"


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _e(text: str) -> str:
    return html.escape(text, quote=True)


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _json_for_script(data) -> str:
    """JSON that cannot end its <script> element early."""
    return json.dumps(data, separators=(",", ":")).replace("<", "\\u003c").replace(">", "\\u003e")


def _exists(path: Path | None) -> bool:
    return path is not None and Path(path).exists()


def _read_json(path: Path | None) -> dict:
    if not _exists(path):
        return {}
    return json.loads(Path(path).read_text())
