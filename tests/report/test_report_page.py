"""report.html of a sparse run: self-contained, every figure decodes in Chromium, no console error,
the 3D viewer draws something and changes when orbited; per-photo table; unregistered photos explained."""

from __future__ import annotations

import base64
import html
import io
import json
import re
import shutil
from html.parser import HTMLParser

import numpy as np
import pytest
import trimesh

from recon.mvs.colmap_io import write_map
from recon.report import Limits, Sources, build_report
from recon.report.page import THREE
from recon.surface.export import Z_UP_TO_GLTF, write_glb
from recon.surface.texture.model import TexturedMesh

PLOTS = {"per-image", "pair-matrix", "track-lengths", "reprojection-errors", "top-view", "side-view", "pose-auc"}


class Rows(HTMLParser):
    """The per-photo table's rows (name, registered, cells) and the unregistered list's items."""

    def __init__(self):
        super().__init__()
        self.rows: list[tuple[str, bool, list[str]]] = []
        self.unregistered: list[str] = []
        self._cells: list[str] | None = None
        self._row: tuple[str, bool] | None = None
        self._in_list = self._in_item = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "tr" and "data-image" in a:
            self._row, self._cells = (a["data-image"], a.get("class") == "registered"), []
        elif tag == "td" and self._cells is not None:
            self._cells.append("")
        elif tag == "ul" and a.get("id") == "unregistered":
            self._in_list = True
        elif tag == "li" and self._in_list:
            self.unregistered.append("")
            self._in_item = True

    def handle_endtag(self, tag):
        if tag == "tr" and self._row is not None:
            self.rows.append((*self._row, self._cells))
            self._row = self._cells = None
        elif tag == "ul":
            self._in_list = False
        elif tag == "li":
            self._in_item = False

    def handle_data(self, data):
        if self._cells:
            self._cells[-1] += data
        if self._in_item:
            self.unregistered[-1] += data


def parse(html: str) -> Rows:
    p = Rows()
    p.feed(html)
    return p


def test_report_is_self_contained(report_workspace):
    page = (report_workspace / "report.html").read_text()
    # nothing fetched from elsewhere: no external scripts, styles or images
    assert not re.search(r'<(script|img|link|iframe)[^>]+(src|href)="(?!data:)', page)
    assert "Three.js Authors" in page and "OrbitControls" in page
    assert len(re.findall(r'<img [^>]*data-plot="([^"]+)"[^>]*src="data:image/png;base64,', page)) >= len(PLOTS)


def test_report_lists_every_photo_with_its_figures(report_workspace, sparse_workspace):
    import pycolmap

    page = parse((report_workspace / "report.html").read_text())
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    assert len(page.rows) == 16 and all(registered for _, registered, _ in page.rows)
    assert page.unregistered == []
    for name, _, cells in page.rows:
        image = rec.find_image_with_name(name)
        keypoints, observations, error = int(cells[3]), int(cells[6]), float(cells[7])
        assert keypoints == image.num_points2D()
        assert observations == image.num_points3D
        assert 0 < error < 2
    text = (report_workspace / "report.html").read_text()
    assert "auc@5" in text  # the evaluation against the scene's ground truth


def test_report_in_headless_chromium(report_workspace, browser):
    browser.open((report_workspace / "report.html").resolve().as_uri())
    browser.wait_for("document.getElementById('viewer').dataset.state === 'ready'")
    images = browser.evaluate("[...document.images].map(i => [i.dataset.plot, i.complete, i.naturalWidth, "
                              "i.naturalHeight])")
    shown = {name for name, complete, w, h in images if complete and w > 0 and h > 0}
    assert PLOTS <= shown, f"missing or undecoded: {PLOTS - shown}"
    assert len(shown) == len(images)
    before = browser.screenshot("#viewer canvas")
    assert before.shape[0] > 200 and before.std() > 8, "the viewer's canvas is blank"
    browser.drag("#viewer canvas", 220, 40)
    after = browser.screenshot("#viewer canvas")
    changed = np.abs(after.astype(int) - before.astype(int)).max(axis=2) > 30
    assert changed.mean() > 0.005, "orbiting did not change the view"
    assert browser.errors() == []


def test_report_shows_dense_maps_mesh_and_textured_model(small_scene, sparse_workspace, tmp_path, browser):
    """Every optional section, built from the scene's ground truth as stand-in dense outputs."""
    stereo = tmp_path / "dense" / "stereo"
    for view in ("view_000.jpg", "view_005.jpg"):
        stem = view.removesuffix(".jpg")
        write_map(stereo / "depth_maps" / f"{view}.geometric.bin", np.load(small_scene / "gt" / "depth" / f"{stem}.npy"))
        write_map(stereo / "normal_maps" / f"{view}.geometric.bin", np.load(small_scene / "gt" / "normal" / f"{stem}.npy"))
    mesh = trimesh.load(small_scene / "gt" / "mesh.ply", process=False)
    points, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    trimesh.PointCloud(points, colors=np.tile([200, 120, 40, 255], (len(points), 1))).export(tmp_path / "fused.ply")
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([90, 160, 220, 255], (len(mesh.vertices), 1)))
    mesh.export(tmp_path / "mesh.ply")
    mesh.copy().apply_transform(Z_UP_TO_GLTF).export(tmp_path / "textured.glb")  # glTF's Y up, as write_glb
    sources = Sources(database=sparse_workspace / "database.db", model=sparse_workspace / "sparse" / "0",
                      stereo=stereo, fused=tmp_path / "fused.ply", mesh=tmp_path / "mesh.ply",
                      textured=tmp_path / "textured.glb")
    report = build_report(sources, title="all sections")
    assert report.summary["depth_maps"] == 2 and report.summary["dense_points"] == 20000
    assert report.summary["mesh_faces"] == len(mesh.faces)
    page = tmp_path / "report.html"
    page.write_text(report.html)
    assert ">watertight<" in report.html and "textured mesh" in report.html

    browser.open(page.as_uri())
    browser.wait_for("document.getElementById('viewer').dataset.state === 'ready'")
    names = browser.evaluate("[...document.images].filter(i => i.complete && i.naturalWidth > 0)"
                             ".map(i => i.dataset.plot)")
    assert {"depth:view_000.jpg", "normal:view_000.jpg", "depth:view_005.jpg", "normal:view_005.jpg"} <= set(names)
    layers = browser.evaluate("[...document.querySelectorAll('#viewer .layers label')].map(l => l.textContent)")
    assert [label.split(" (")[0].strip() for label in layers] == ["cameras", "sparse points", "dense points",
                                                                  "textured mesh"]
    assert browser.screenshot("#viewer canvas").std() > 8
    assert browser.errors() == []


def test_unregistered_photos_are_named_with_the_reason(small_scene, tmp_path, run_report):
    """Ten photos of the synthetic scene and three of other scenes (two overlapping crops of one photo,
    one of another; the synthetic scenes of other seeds share their textures, so they would register)."""
    import skimage.data
    from PIL import Image

    images = tmp_path / "images"
    images.mkdir()
    for k in range(10):
        shutil.copy(small_scene / "images" / f"view_{k:03d}.jpg", images)
    astronaut, rocket = skimage.data.astronaut(), skimage.data.rocket()
    foreign = {"other_a.jpg": astronaut[40:340, 0:400], "other_b.jpg": astronaut[100:400, 80:480],
               "other_c.jpg": rocket[60:420, 80:560]}
    for name, pixels in foreign.items():
        Image.fromarray(pixels).resize((320, 240), Image.Resampling.LANCZOS).save(images / name, quality=95)
    ws = tmp_path / "ws"
    run_report(images, ws)
    page = parse((ws / "report.html").read_text())
    registered = {name for name, reg, _ in page.rows if reg}
    assert registered == {f"view_{k:03d}.jpg" for k in range(10)}
    reasons = dict(item.split(": ", 1) for item in page.unregistered)
    assert set(reasons) == set(foreign)
    assert reasons["other_c.jpg"].startswith("too few matches")
    for why in reasons.values():
        assert re.match(r"too few matches|registration failed|registered in separate model", why), why
    rows = {name: cells for name, _, cells in page.rows}
    for name in foreign:
        assert rows[name][1] == "no" and rows[name][-1] == reasons[name]


@pytest.mark.slow
@pytest.mark.datasets
def test_temple_ring_report_lists_47_registered_photos(datasets, tmp_path, run_report):
    images = datasets / "temple_ring" / "images"
    if not images.is_dir():
        pytest.skip(f"{images} absent")
    ws = tmp_path / "temple"
    run_report(images, ws, [f"report.gt={datasets / 'temple_ring'}"])
    page = parse((ws / "report.html").read_text())
    assert len(page.rows) == 47
    registered = [cells for _, reg, cells in page.rows if reg]
    assert len(registered) == 47, page.unregistered
    for cells in registered:
        assert int(cells[3]) > 100 and int(cells[5]) > 0 and int(cells[6]) > 0 and 0 < float(cells[7]) < 2
    assert "auc@5" in (ws / "report.html").read_text()


def _viewer_data(page: str) -> dict:
    return json.loads(re.search(r'<script id="viewer-data" type="application/json">(.*?)</script>', page, re.S)[1])


def _quadrant_texture_model(points: np.ndarray, path, cells: int = 160, texels: int = 1024):
    """A wavy open sheet over the sparse points, textured red / green / blue / yellow by quadrant (with
    noise, so the PNG is large), written as textured.glb; returns its world vertices."""
    lo, hi = np.percentile(points, [10, 90], axis=0)
    u, v = np.meshgrid(np.linspace(0, 1, cells + 1), np.linspace(0, 1, cells + 1))
    z = np.median(points[:, 2]) + 0.03 * (hi[0] - lo[0]) * np.sin(12 * u) * np.cos(9 * v)
    vertices = np.column_stack([lo[0] + u.ravel() * (hi[0] - lo[0]), lo[1] + v.ravel() * (hi[1] - lo[1]), z.ravel()])
    idx = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    uv = np.column_stack([u.ravel(), v.ravel()])[faces]
    half = texels // 2
    texture = np.zeros((texels, texels, 3), np.int16)
    texture[:half, :half], texture[:half, half:] = (220, 30, 30), (30, 200, 30)   # top of the image: v near 1
    texture[half:, :half], texture[half:, half:] = (30, 60, 230), (230, 210, 30)
    texture += np.random.default_rng(0).integers(-25, 26, texture.shape, dtype=np.int16)
    textured = TexturedMesh(vertices, faces, uv, np.clip(texture, 0, 255).astype(np.uint8),
                            np.zeros(len(faces), np.int64), np.zeros((len(vertices), 3), np.uint8))
    write_glb(textured, path)
    return vertices


def test_large_textured_model_is_shown_as_a_page_copy(sparse_workspace, tmp_path, browser):
    """A textured.glb over the size limit is embedded as a decimated copy with a smaller baked texture:
    the page stays small, the copy sits where the model is, and Chromium draws its texture's colours."""
    from recon.report.gather import read_model

    model, _ = read_model(sparse_workspace / "sparse" / "0")
    vertices = _quadrant_texture_model(model.points, tmp_path / "textured.glb")
    glb_size = (tmp_path / "textured.glb").stat().st_size
    assert glb_size > 3_000_000
    sources = Sources(database=sparse_workspace / "database.db", model=sparse_workspace / "sparse" / "0",
                      textured=tmp_path / "textured.glb")
    limits = Limits(max_glb_bytes=1_000_000, model_faces=3000, model_texture=512)
    report = build_report(sources, title="large model", limits=limits)
    assert len(report.html) - THREE.stat().st_size < 1_500_000  # the figures, the points and the copy
    assert "shown as a copy made for this page" in report.html

    data = _viewer_data(report.html)
    layer = next(layer for layer in data["layers"] if layer["id"] == "textured")
    copy = trimesh.load(io.BytesIO(base64.b64decode(layer["data"])), file_type="glb", force="mesh")
    assert 2000 < len(copy.faces) <= 3000 and max(copy.visual.material.baseColorTexture.size) <= 512
    copy.apply_transform(np.array(layer["matrix"]).reshape(4, 4).T)  # into the viewer's frame
    assert np.allclose(copy.bounds, np.array([vertices.min(0), vertices.max(0)]) - data["origin"],
                       atol=0.02 * np.ptp(vertices[:, 0]))
    # the baked texture puts each quadrant's colour where the model has it
    centre = copy.triangles_center + data["origin"]
    u, v = ((centre[:, :2] - vertices.min(0)[:2]) / np.ptp(vertices[:, :2], axis=0)).T
    clear = (np.abs(u - 0.5) > 0.03) & (np.abs(v - 0.5) > 0.03)
    expected = np.where(v > 0.5, np.where(u < 0.5, 0, 1), np.where(u < 0.5, 2, 3))  # red, green, blue, yellow
    texture = np.asarray(copy.visual.material.baseColorTexture.convert("RGB"), float)
    face_uv = copy.visual.uv[copy.faces].mean(axis=1)
    colour = texture[((1 - face_uv[:, 1]) * texture.shape[0]).astype(int).clip(0, texture.shape[0] - 1),
                     (face_uv[:, 0] * texture.shape[1]).astype(int).clip(0, texture.shape[1] - 1)]
    palette = np.array([(220, 30, 30), (30, 200, 30), (30, 60, 230), (230, 210, 30)], float)
    nearest = np.linalg.norm(colour[:, None] - palette[None], axis=2).argmin(axis=1)
    assert (nearest[clear] == expected[clear]).mean() > 0.97

    page = tmp_path / "report.html"
    page.write_text(report.html)
    browser.open(page.as_uri())
    browser.wait_for("document.getElementById('viewer').dataset.state === 'ready'")
    browser.evaluate("[...document.querySelectorAll('#viewer .layers label')].filter(l => "
                     "!l.textContent.includes('textured')).forEach(l => l.querySelector('input').click())")
    pixels = browser.screenshot("#viewer canvas").astype(int)
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    shares = {"red": ((r > 1.8 * g) & (r > 1.8 * b)).mean(), "green": ((g > 1.8 * r) & (g > 1.8 * b)).mean(),
              "blue": ((b > 1.8 * r) & (b > 1.8 * g)).mean(), "yellow": ((r > 2 * b) & (g > 2 * b)).mean()}
    assert min(shares.values()) > 0.002, shares  # a grey, untextured sheet has none of them
    assert browser.errors() == []


def test_mean_reprojection_error_is_the_sfm_stages(report_workspace):
    """One definition: the page's mean reprojection error is the sfm stage's (COLMAP's mean over points
    of each point's mean error), not the mean over observations, and the page says which it is."""
    import pycolmap

    from recon.workspace import Workspace

    page = (report_workspace / "report.html").read_text()
    shown = float(re.search(r"<b>([0-9.]+) px</b><span>mean reprojection error</span>", page)[1])
    ws = Workspace(report_workspace)
    logged = ws.manifest("sfm", ws.state()["sfm"])["summary"]["mean_reproj_error"]
    assert shown == logged
    rec = pycolmap.Reconstruction(str(report_workspace / "sparse" / "0"))
    per_observation = []
    for image in rec.images.values():
        cam = rec.camera(image.camera_id)
        for p in image.points2D:
            if p.has_point3D():
                xy = cam.img_from_cam(image.cam_from_world() * rec.point3D(p.point3D_id).xyz)
                per_observation.append(np.linalg.norm(np.asarray(xy) - p.xy))
    assert round(float(np.mean(per_observation)), 3) != logged  # the two definitions differ on this scene
    assert html.escape("COLMAP's definition, the figure the sfm stage logs") in page


def test_evaluation_shows_the_fused_clouds_reprojection():
    figures = {"fused_reprojection": {"median_px": 0.4321, "p90_px": 1.234, "observations": 12345, "points": 678}}
    page = build_report(Sources(), title="evaluation", evaluation=figures, limits=Limits(viewer=False)).html
    table = re.search(r'<div id="fused-reprojection">(.*?)</div>', page, re.S)[1]
    for text in ("0.43 px", "1.23 px", "12345", "678"):
        assert text in table


def test_sfm_note_shows_weak_joins_and_the_false_pairs_left_out():
    """models.json's weak-joins warning and the global mapper's false pairs reach the page, escaped."""
    from recon.report.page import _mapper_note

    registration = {"mapper": {"used": "global", "why": "the incremental mapper's largest model holds 9 of 29 photos",
                               "false_pairs": ["view_009.jpg / view_025.jpg (16 inliers, 6% agree)"]},
                    "weak_joins": {"warning": "the model's photos fall into 2 groups <b>"}}
    note = _mapper_note(registration)
    assert '<p class="bad" id="weak-joins">The model&#x27;s photos fall into 2 groups &lt;b&gt;.</p>' in note
    assert 'id="false-pairs"' in note and "view_009.jpg / view_025.jpg (16 inliers, 6% agree)" in note
    assert "weak-joins" not in _mapper_note({"weak_joins": {"min_points": 30, "groups": [["a.jpg"]], "joins": []}})
