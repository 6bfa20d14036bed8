"""``make bench-quality``: the full pipeline on every scene of the zoo (recon.synth.zoo), one table.

Per scene: registered views, the fused cloud's and the mesh's F-score at 0.2 % and 0.5 % of the
scene's extent (recon.eval.surface, through ``recon.api.evaluate``: the model is aligned to the
ground truth on its camera centres and axes, refined on its sparse points' reprojection in the true
cameras; recon.eval.workspace says why), and in the scene's held-out views the
masked PSNR of the textured mesh beside that of the vertex-coloured mesh (the baseline a texture
must beat) and the texture's coverage; seconds to render the scene (meant to be under a minute at 640x480;
near 0 where an earlier run's rendering is reused) and per stage. Then the mean and the worst scene. Beside
them, to tell which part of the chain lost a scene's quality: the cameras' relative-pose AUC at 5
degrees (sfm) and the final depth maps' accuracy and completeness at 0.2 % (mvs; recon.eval.depth).
And ``maxF``, the highest fused F@0.2 % the scene allows: a fused point needs two views, and some of the
observable surface only one photo sees (:func:`seen_twice`); beside coverage, ``seen2``, the share of the
held-out views' surface that two input views see (:func:`holdout_seen_twice`). Below the table, the fused
cloud's accuracy and completeness at 0.2 %, and its completeness where 1, 2, 3-4 and 5 or more input views
see the surface (:func:`completeness_by_views`): where fused F falls short of ``maxF``, which surface the
depth maps miss. At session 45 the wide scenes' clouds were accurate and incomplete (walkaround 99.7 % /
76.0 %, aerial_grid 99.6 / 84.6), the object scenes' balanced (turntable_black 96.0 / 96.2).

- PSNR is over the pixels where the rendered mesh and the true surface both are (recon.eval.texture).
  The mesh is rendered as the held-out photos were (:func:`render_as_photographed`): their renderer casts
  3 x 3 rays at silhouettes and depth edges, and until session 56 the bench cast one ray per pixel, which
  cost even a perfect model: the true scene rendered so scored 32.2-41.2 dB in the zoo's held-out views
  (turntable_black 34.8), against 35.0-43.4 rendered as the photos were (their JPEG alone).
- PSNR twice: with the held-out views at their true poses, taken into the model's frame by the alignment
  above (``texPSNR``, ``vcPSNR``), and with the views placed in the model by ``recon localize`` from
  their own photos (``texPl``, ``vcPl``), as a user places a new photo. The first counts every error of
  the model's shape against the truth; the second what the texture shows from the model's own
  viewpoints. A model bent within the noise of its poses loses a pixel or more at the true poses: zoo
  walkaround at session 38, the four sides of a building joined by few points at its corners, its
  sparse points a median of up to 1.9 px off their features in the true cameras after the alignment;
  texture 25.57 dB at the true poses, 30.07 placed; vertex colours 24.05 and 24.83.
- Below the table, the angle between the mesh and the true surface's normal where the mesh lies within
  0.2 % of it (median and 90th percentile, :func:`mesh_normals`): a flat face that comes out bumpy, or an
  edge rounded off, which shading shows at once and the F-scores, counting distance alone, hardly see.
  Session 55, before `mesh.denoise`: turntable_black 6.0 / 31.0 degrees, clutter 5.5 / 32.6, walkaround
  2.6 / 11.5, plain_boxes 1.8 / 6.6.
- ``vtx/px``: the mesh's vertices a held-out view sees per pixel of its true surface
  (:func:`vertices_per_pixel`). Where it nears 1, vertex colours sample the surface as finely as the
  photos, and the texture's lead over them shrinks to what the photos' blending and resampling add:
  zoo session 42, masked_object 3.9 vertices per pixel, texture +0.30 dB over vertex colours;
  turntable_black 0.63, +0.51; the other 15 scenes 0.05-0.21, +1.5 (glossy, whose highlights no
  texture shows) and +2.5 to +10.1.
- PSNR a third time, over the held-out pixels (at the true poses) where the textured mesh's surface lies
  within 0.2 % of the extent of the true depth (``true_shape``, their share of the surface): what the
  texture shows where the shape is right, beside the vertex colours there. Elsewhere a pixel shows the
  wrong surface (a silhouette off by a pixel, a hole) in both renderings alike, and those pixels dominate
  both PSNRs: on session 45's turntable_black workspace the 3.5 % of its surface where the mesh lay more
  than 0.4 % off showed 16.4 dB and made 72 % of the texture's squared error; where the mesh lay within
  0.2 % (91.4 %), texture 35.39 dB, vertex colours 34.33.
- Where a scene has glossy parts, its held-out photos show highlights that move from view to view, and
  no texture (one colour per surface point) shows them; the scene ships each held-out view rendered
  without them (recon.synth.dataset: ``holdout/diffuse``). ``psnr_ceiling`` is that rendering's PSNR
  against the photo over its surface: what a texture holding the surface's true colours, on the true
  shape, scores. Beside it, the textured and the vertex-coloured mesh against that rendering
  (``psnr_diffuse``, ``psnr_vertex_colours_diffuse``): how near the texture comes to those colours.
- Coverage is the share of the held-out views' true-surface pixels (ground-truth depth > 0; in a
  masked scene, those of the masked object) that the textured mesh covers.
- A scene whose pipeline fails counts as F = 0 and coverage 0 in the mean and the worst (its error
  is printed); its PSNR is left out, as is the PSNR of a scene whose mesh shows nothing in its
  held-out views.
- ``masked_object`` runs with ``preprocess.mask_dir`` set to the masks it ships, and its fused cloud
  and mesh are scored against the masked object alone (against the whole scene, the room and the
  table the masks keep out counted as missing: fused F@0.2 % 0.014), on the part of its surface some
  input view sees, as the other scenes are (its underside, which it stands on, left out:
  :func:`object_figures`).

Results go to ``<out>/quality.json`` (figures per scene and the summary); ``--compare BEFORE AFTER``
prints two such files side by side (:func:`compare`). Scenes render once into
``<out>/quality/<scene>/scene`` and are reused while their size, view count and definition
(``recon.synth.zoo.zoo_digest``) match.

    python -m recon.bench --only quality [--scenes a,b] [--size 640x480] [--views N] [-o key=value]...
    python -m recon.quality_bench --compare before/quality.json after/quality.json
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import recon
import recon.api

REPO = Path(__file__).resolve().parents[1]
CONFIG = Path(__file__).resolve().parent / "pipelines" / "full.yaml"
TAUS = ("0.002", "0.005")
SUPERSAMPLE = 3  # rays per pixel side where the held-out photos were anti-aliased (recon.synth.render)
#: how the held-out PSNRs rendered the models (quality.json's ``texture_rendering``; runs before it was recorded
#: cast one ray per pixel): two runs rendered differently do not compare
TEXTURE_RENDERING = "as photographed"
STAGES = ("ingest", "preprocess", "features", "matching", "sfm", "export", "undistort", "mvs", "fusion", "mesh",
          "texture")


def scene_for(name: str, root: Path, width: int, height: int, views: int | None):
    """The rendered zoo scene ``name`` under ``root`` (rendered when absent, of another size, or made
    from an earlier definition of the scene: ``<root>.digest`` holds the zoo's digest of the rendering)."""
    from recon.synth import load_scene
    from recon.synth.zoo import render_zoo, zoo_digest

    digest = zoo_digest(name)
    stamp = root.with_name(root.name + ".digest")
    try:
        info = load_scene(root)
        if info.name == name and (info.width, info.height) == (width, height) and views in (None, info.views) \
                and stamp.is_file() and stamp.read_text() == digest:
            return info
    except FileNotFoundError:
        pass
    info = render_zoo(name, root, views=views, width=width, height=height)
    stamp.write_text(digest)
    return info


def holdout_texture(ws: Path, scene) -> dict:
    """Masked PSNR of the textured and the vertex-coloured mesh and the texture's coverage, averaged over
    the scene's held-out views at their true poses; both PSNRs again over the pixels where the textured
    mesh lies within 0.2 % of the extent of the true depth, and those pixels' share of the surface
    (``true_shape``); and the PSNRs with the views placed in the model (:func:`placed_holdout`); for a scene
    with highlights, both PSNRs against its held-out views' rendering without them (module doc)."""
    import trimesh
    from PIL import Image

    from recon.eval.texture import masked_psnr
    from recon.surface.export import read_glb

    meshes = {"texture": read_glb(ws / "textured.glb"), "vertex_colours": trimesh.load(ws / "mesh.ply", process=False)}
    truth_scene = true_scene(scene)
    placed = placed_holdout(ws, scene, meshes, truth_scene)
    sim = recon.api.model_to_ground_truth(ws, scene.root)
    for mesh in meshes.values():
        mesh.vertices = sim.apply(np.asarray(mesh.vertices))
    tolerance = float(TAUS[0]) * scene.extent
    psnr: dict[str, list[float]] = {k: [] for k in meshes}
    on_shape: dict[str, list[float]] = {k: [] for k in meshes}
    vs_diffuse: dict[str, list[float]] = {k: [] for k in meshes}
    coverage, density, shape = [], [], []
    for name, cam in scene.cameras(holdout=True).items():
        truth = np.asarray(Image.open(scene.holdout_images_dir / name).convert("RGB"))
        diffuse = _diffuse_holdout(scene, name)
        depth = scene.depth(name)
        surface = holdout_surface(scene, name, depth)
        density.append(vertices_per_pixel(np.asarray(meshes["vertex_colours"].vertices), cam, depth, surface,
                                          tolerance))
        rays = _true_rays(cam)  # (directions of camera z = 1: a hit's distance along the ray is its depth)
        for key, mesh in meshes.items():  # the texture first: its shape picks the pixels ``right``
            image, mask, hits = render_as_photographed(mesh, rays, depth, truth_scene)
            if key == "texture":
                right = surface & (np.abs(hits - depth) <= tolerance)
                shape.append(float(np.count_nonzero(right) / max(np.count_nonzero(surface), 1)))
                coverage.append(float(np.count_nonzero(mask & surface) / max(np.count_nonzero(surface), 1)))
            if (mask & surface).any():  # no PSNR where the mesh shows nothing of the surface
                psnr[key].append(masked_psnr(image, truth, mask & surface))
                if diffuse is not None:
                    vs_diffuse[key].append(masked_psnr(image, diffuse, mask & surface))
            if right.any():
                on_shape[key].append(masked_psnr(image, truth, right))
    out = {"coverage": float(np.mean(coverage)), "vertices_per_pixel": float(np.mean(density)),
           "true_shape": float(np.mean(shape))}
    if psnr["texture"]:
        out |= {"psnr": float(np.mean(psnr["texture"])), "psnr_vertex_colours": float(np.mean(psnr["vertex_colours"]))}
    if on_shape["texture"]:
        out |= {"psnr_true_shape": float(np.mean(on_shape["texture"])),
                "psnr_vertex_colours_true_shape": float(np.mean(on_shape["vertex_colours"]))}
    if vs_diffuse["texture"]:
        out |= {"psnr_diffuse": float(np.mean(vs_diffuse["texture"])),
                "psnr_vertex_colours_diffuse": float(np.mean(vs_diffuse["vertex_colours"]))}
    return out | placed


def vertices_per_pixel(vertices: np.ndarray, cam, depth: np.ndarray, surface: np.ndarray, tolerance: float) -> float:
    """How many of the mesh's ``vertices`` (world frame) a held-out view (``cam``, its true ``depth``) sees per
    pixel of its true ``surface``: those imaged on that surface within ``tolerance`` of its depth. Near 1 and
    above, the vertex-coloured mesh samples the surface as finely as the photo does, and no texture can show
    much more than its vertex colours (the ``vtx/px`` column)."""
    uv, z = cam.project(vertices)
    height, width = depth.shape
    inside = (z > 0) & np.all(uv >= 0, axis=1) & (uv[:, 0] < width) & (uv[:, 1] < height)
    cols, rows = uv[inside].astype(int).T
    seen = surface[rows, cols] & (np.abs(z[inside] - depth[rows, cols]) <= tolerance)
    return float(np.count_nonzero(seen) / max(np.count_nonzero(surface), 1))


def placed_holdout(ws: Path, scene, meshes: dict, truth_scene: TrueScene) -> dict:
    """Masked PSNR of ``meshes`` (``texture``, ``vertex_colours``; in the model's frame) in the held-out
    views where ``recon localize`` places them in the model, through the model's camera (its distortion
    too): ``psnr_placed`` and ``psnr_vertex_colours_placed``, means over the views placed and showing the
    surface; ``placed``, how many views were placed. The placement is written beside the workspace."""
    import pycolmap
    from PIL import Image

    from recon.eval.texture import masked_psnr
    from recon.products import Published

    result = recon.api.localize(ws, scene.holdout_images_dir, out=ws.parent / "holdout_placed")
    model = pycolmap.Reconstruction(str(Published(result["workspace"]).model()))
    images = {Path(image.name).name: image for image in model.images.values()}
    names = sorted(Path(p["name"]).name for p in result["photos"] if p["placed"])
    psnr: dict[str, list[float]] = {k: [] for k in meshes}
    for name in names:
        truth = np.asarray(Image.open(scene.holdout_images_dir / name).convert("RGB"))
        depth = scene.depth(name)
        surface = holdout_surface(scene, name, depth)
        image = images[name]
        rays = _photo_rays(model.camera(image.camera_id), image.cam_from_world(), truth.shape[1], truth.shape[0])
        for key, mesh in meshes.items():
            rendered, mask, _ = render_as_photographed(mesh, rays, depth, truth_scene)
            if (mask & surface).any():
                psnr[key].append(masked_psnr(rendered, truth, mask & surface))
    out = {"placed": len(names)}
    if psnr["texture"]:
        out |= {"psnr_placed": float(np.mean(psnr["texture"])),
                "psnr_vertex_colours_placed": float(np.mean(psnr["vertex_colours"]))}
    return out


Rays = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Pixel positions (N, 2) of a view -> world origins and directions (N, 3; camera z = 1) of their rays."""


def _true_rays(cam) -> Rays:
    """The rays of the ground-truth camera ``cam`` (its lens's distortion undone)."""
    return lambda px: _world_rays(cam.rays(px), cam.R, cam.center)


def _photo_rays(camera, cam_from_world, width: int, height: int) -> Rays:
    """The rays of a ``width`` x ``height`` photo taken by the COLMAP ``camera`` (its distortion undone) at
    ``cam_from_world``."""
    R = cam_from_world.rotation.matrix()
    centre = -R.T @ cam_from_world.translation
    scale = np.array([camera.width / width, camera.height / height])

    def rays(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = camera.cam_from_img(np.asarray(px, np.float64) * scale)
        return _world_rays(np.column_stack([xy, np.ones(len(xy))]), R, centre)
    return rays


def _world_rays(directions: np.ndarray, R: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World origins and directions (N, 3) of a camera's rays of camera-frame ``directions`` (N, 3), given its
    world-to-camera rotation ``R`` and its ``centre``."""
    world = directions @ R
    return np.broadcast_to(centre, world.shape), world


def _pixel_grid(rays: Rays, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions (height, width, 3) of the rays through every pixel centre."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    origins, directions = rays(np.column_stack([u.ravel(), v.ravel()]))
    return origins.reshape(height, width, 3), directions.reshape(height, width, 3)


def render_as_photographed(mesh, rays: Rays, true_depth: np.ndarray,
                           truth: TrueScene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``mesh`` rendered into a held-out view the way its photo was rendered (recon.synth.render): a ray
    through each pixel centre and, at the pixels whose 8-neighbourhood crosses a silhouette or a depth jump
    in the view's ``true_depth`` or the mesh's own, the mean of :data:`SUPERSAMPLE` x :data:`SUPERSAMPLE`
    rays. A ray that misses the mesh shows the scene's background, unless what it shows beyond the model is
    unknown (:meth:`TrueScene.backdrop_unknown`: a masked scene's model holds its object alone, not the room
    around it); then it is left out of its pixel's mean. Image (H, W, 3; float 0-255), the pixel centres that
    hit the mesh, and where along their rays (camera z; inf on a miss). One ray per pixel against photos anti-aliased at their silhouettes
    costs even a perfect model: the true scene rendered so scores 34.8 dB in zoo turntable_black's held-out
    views, against 41.7 rendered as the photos were (their JPEG alone)."""
    from recon.eval.texture import first_hits, render_rays
    from recon.synth.render import background_colours, edge_pixels

    height, width = true_depth.shape
    origins, directions = _pixel_grid(rays, width, height)
    image, mask = render_rays(mesh, origins, directions)
    hits = first_hits(mesh, origins, directions)
    rows, cols = np.nonzero(edge_pixels(true_depth > 0, true_depth) | edge_pixels(mask, np.where(mask, hits, 0.0)))
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE
    dy, dx = np.meshgrid(offsets, offsets, indexing="ij")
    sub_origins, sub_directions = rays(np.stack([cols[:, None] + dx.ravel(), rows[:, None] + dy.ravel()],
                                                -1).reshape(-1, 2))
    colour, shown = (a[:, 0] for a in render_rays(mesh, sub_origins[:, None], sub_directions[:, None]))
    missed = np.flatnonzero(~shown)
    backdrop = missed[~truth.backdrop_unknown(sub_origins[missed], sub_directions[missed])]
    colour[backdrop] = 255.0 * background_colours(truth.background, sub_directions[backdrop])
    shown[backdrop] = True
    shown = shown.reshape(len(rows), -1)
    count = shown.sum(axis=1)
    keep = count > 0
    total = np.einsum("pk,pkc->pc", shown, colour.reshape(len(rows), -1, 3))
    image[rows[keep], cols[keep]] = total[keep] / count[keep, None]
    return image, mask, hits


@dataclass(frozen=True)
class TrueScene:
    """What :func:`render_as_photographed` needs of a synthetic scene: a ray-casting scene of its true surface
    (``whole``), whether a model of it holds its masked object alone (``masked``), and what a ray missing the
    scene shows (``background``, recon.synth.render's)."""

    whole: object
    masked: bool
    background: object

    def backdrop_unknown(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether what each ray (N, 3 origins and directions) shows beyond the model is unknown: in a masked
        scene, a ray that meets a true surface (the model holds the object alone, not the room around it)."""
        from recon.surface.raycast import cast

        if not self.masked:
            return np.zeros(len(origins), bool)
        return np.isfinite(cast(self.whole, origins, directions)["t"])


def true_scene(scene) -> TrueScene:
    """The synthetic ``scene``'s :class:`TrueScene`: a zoo scene's own background, any other's the default
    sky (recon.synth.dataset)."""
    import trimesh

    from recon.surface.raycast import scene_of
    from recon.synth.render import SKY
    from recon.synth.zoo import SCENES, zoo_setup

    mesh = trimesh.load(scene.mesh_path, process=False, force="mesh")
    return TrueScene(scene_of(np.asarray(mesh.vertices), np.asarray(mesh.faces)), bool(scene.masked),
                     zoo_setup(scene.name).background if scene.name in SCENES else SKY)


def holdout_surface(scene, name: str, depth: np.ndarray) -> np.ndarray:
    """The pixels of held-out view ``name`` (its ground-truth ``depth``) that coverage and PSNR count: the true
    surface (depth > 0), in a masked scene the masked object's only (the masks keep the rest out of the
    texture)."""
    from recon.imaging.masks import load_mask

    surface = depth > 0
    if scene.masked:
        surface &= load_mask(scene.holdout_masks_dir, name, surface.shape)
    return surface


def texture_ceiling(scene) -> dict:
    """For a scene with highlights (its held-out views rendered without them ship with it), ``psnr_ceiling``:
    the mean PSNR of those renderings against the held-out photos over their surface, what a texture of the
    surface's true colours on the true shape scores (module doc); for any other scene, nothing."""
    from PIL import Image

    from recon.eval.texture import masked_psnr

    psnr = []
    for name in scene.cameras(holdout=True):
        diffuse = _diffuse_holdout(scene, name)
        if diffuse is not None:
            truth = np.asarray(Image.open(scene.holdout_images_dir / name).convert("RGB"))
            psnr.append(masked_psnr(diffuse, truth, holdout_surface(scene, name, scene.depth(name))))
    return {"psnr_ceiling": float(np.mean(psnr))} if psnr else {}


def _diffuse_holdout(scene, name: str) -> np.ndarray | None:
    """Held-out view ``name`` rendered without highlights (RGB), where the scene ships it."""
    from PIL import Image

    path = scene.holdout_diffuse_dir / name
    return np.asarray(Image.open(path).convert("RGB")) if path.is_file() else None


def holdout_seen_twice(scene) -> float:
    """The share of the held-out views' surface pixels (what coverage counts) whose surface two input views or
    more see (recon.eval.surface.views_seeing): what depth maps can measure of it, the ``seen2`` column. It
    does not bound coverage: Poisson closes the surface across what one photo alone sees, and so may cover
    more. Where a scene's coverage lies above it, the excess stands on surface no two photos measured."""
    from recon.eval.surface import views_seeing

    seen = total = 0
    for name, cam in scene.cameras(holdout=True).items():
        depth = scene.depth(name)
        rows, cols = np.nonzero(holdout_surface(scene, name, depth))
        points = cam.backproject(np.column_stack([cols + 0.5, rows + 0.5]), depth[rows, cols])
        seen += int(np.count_nonzero(views_seeing(scene, points) >= 2))
        total += len(points)
    return seen / max(total, 1)


def object_figures(ws: Path, scene) -> dict:
    """The fused cloud's and the mesh's figures against the masked object alone (recon.eval.surface.
    object_metrics): the masks keep everything else out by design, so the rest of the scene is not
    what they are scored on. As on every other scene, completeness counts the surface some input view
    sees (recon.eval.surface.views_seeing), not the underside the object stands on. The thresholds stay
    fractions of the scene's extent, as in every other scene (the object's own diagonal, 0.45 m, would
    make 0.2 % a quarter of a pixel at 320x240)."""
    import trimesh

    from recon.eval.surface import object_metrics, views_seeing
    from recon.products import Published

    def observable(points: np.ndarray) -> np.ndarray:
        return views_seeing(scene, points) >= 1

    sim = recon.api.model_to_ground_truth(ws, scene.root)
    truth = trimesh.load(scene.object_mesh_path, process=False, force="mesh")
    out = {}
    for key, path in (("fused", Published(ws).fused), ("mesh", Published(ws).mesh)):
        geometry = trimesh.load(path, process=False)
        geometry.vertices = sim.apply(np.asarray(geometry.vertices))
        out[key] = object_metrics(geometry, truth, thresholds=tuple(float(t) for t in TAUS), extent=scene.extent,
                                  observable=observable)
    return out


def depth_figures(ws: Path, scene) -> dict:
    """The final depth maps' accuracy and completeness at 0.2 % of the extent and the share of their
    depths on the background, averaged over the views (recon.eval.depth, every 2nd pixel): with the
    poses' AUC they tell which part of the chain lost a scene's quality."""
    from recon.eval.depth import workspace_depth_metrics

    views = workspace_depth_metrics(ws, scene, stride=2).values()
    return {key: float(np.mean([v[key] for v in views])) if views else 0.0
            for key in ("accuracy@0.002", "completeness@0.002", "background")}


def bench_scene(name: str, out: Path, config: Path, overrides: list[str], width: int, height: int,
                views: int | None) -> dict:
    """Render (or reuse) the scene, run the pipeline on it from scratch, evaluate; a dict of figures."""
    start = time.perf_counter()
    scene = scene_for(name, out / name / "scene", width, height, views)
    row: dict = {"scene": name, "views": scene.views, "holdout": scene.holdout, "size": [width, height],
                 "render_seconds": round(time.perf_counter() - start, 2)}
    ws = out / name / "ws"
    shutil.rmtree(ws, ignore_errors=True)
    extra = [f"preprocess.mask_dir={scene.masks_dir}"] if scene.masked else []
    try:
        result = recon.run(config, images=str(scene.images_dir), workspace=str(ws), overrides=[*overrides, *extra])
        row["seconds"] = {k: round(v, 2) for k, v in result.seconds.items()}
        row.update(scene_figures(ws, scene))
    except Exception as exc:  # a failing scene is a result: record it and go on with the others
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
    return row


def surface_views(scene) -> tuple[np.ndarray, np.ndarray]:
    """The observable surface (what one input view or more sees, recon.eval.surface, sampled as the F-scores
    sample it) and how many input views see each of its points (recon.eval.surface.views_seeing)."""
    from recon.eval.surface import observed_points, views_seeing

    points = observed_points(scene, float(TAUS[0]) * scene.extent / 2)
    return points, views_seeing(scene, points)


def seen_twice(counts: np.ndarray) -> float:
    """The share of the observable surface that two input views or more see (``counts``: :func:`surface_views`).
    Fusion merges a point only where two views' depth maps agree on it, and no depth is measured where one
    photo alone sees the surface, so a fused cloud's completeness is at most this share s, and its F-score
    at most 2s / (1 + s): the ``maxF`` column."""
    return float(np.mean(counts >= 2))


#: How many input views see a part of the surface, the groups of :func:`completeness_by_views`: (label,
#: fewest, most)
VIEW_GROUPS = (("1", 1, 1), ("2", 2, 2), ("3-4", 3, 4), ("5+", 5, None))


def completeness_by_views(points: np.ndarray, counts: np.ndarray, cloud: np.ndarray, limit: float) -> dict:
    """Per group of :data:`VIEW_GROUPS`: the share of the observable surface ``points`` that that many input
    views see (``counts``) and the share of it within ``limit`` of a point of ``cloud`` (the fused cloud's
    completeness there; the groups' shares times their completeness sum to its completeness). Where a
    scene's fused F lies below ``maxF``, it tells which surface the depth maps miss: at session 43,
    walkaround's cloud was .51 complete where two views see the surface, .83 where three or four do and
    1.00 where five or more do (docs/DECISIONS.md)."""
    from scipy.spatial import cKDTree

    near = cKDTree(cloud).query(points, distance_upper_bound=limit, workers=-1)[0] <= limit if len(cloud) \
        else np.zeros(len(points), bool)
    out = {}
    for label, fewest, most in VIEW_GROUPS:
        group = counts >= fewest
        if most is not None:
            group &= counts <= most
        if group.any():
            out[label] = {"share": float(np.mean(group)), "completeness": float(np.mean(near[group]))}
    return out


def fused_by_views(ws: Path, scene, points: np.ndarray, counts: np.ndarray) -> dict:
    """:func:`completeness_by_views` of the workspace's fused cloud, aligned to the ground truth as the
    F-scores align it, at 0.2 % of the scene's extent."""
    import trimesh

    from recon.products import Published

    sim = recon.api.model_to_ground_truth(ws, scene.root)
    cloud = sim.apply(np.asarray(trimesh.load(Published(ws).fused, process=False).vertices))
    return completeness_by_views(points, counts, cloud, float(TAUS[0]) * scene.extent)


def f_ceiling(share: float) -> float:
    """The F-score of a perfectly accurate reconstruction complete over ``share`` of the surface."""
    return 2 * share / (1 + share)


def scene_figures(ws: Path, scene) -> dict:
    """The figures of a finished workspace of a zoo scene (the module doc's columns)."""
    figures = recon.api.evaluate(ws, scene.root)
    if scene.masked:
        figures |= object_figures(ws, scene)
    row = {"registered": figures["poses"]["registered"], "pose_auc@5": figures["poses"]["auc@5"] / 100,
           "depth": depth_figures(ws, scene)}
    if not scene.masked:  # (these count the whole scene's surface; a masked scene's is its object's: object_figures)
        points, counts = surface_views(scene)
        row["seen_twice"] = seen_twice(counts)
        row["fused_by_views"] = fused_by_views(ws, scene, points, counts)
    row["holdout_seen_twice"] = holdout_seen_twice(scene)
    # the F-scores, and at 0.2 % which of the two each lacks: a wide scene's cloud is accurate and incomplete
    parts = [f"{part}@{TAUS[0]}" for part in ("accuracy", "completeness")]
    for key in ("fused", "mesh"):
        row[key] = ({f"F@{t}": figures[key][f"fscore@{t}"] / 100 for t in TAUS}
                    | {part: figures[key][part] / 100 for part in parts} if key in figures else {})
    return row | mesh_normals(ws, scene) | holdout_texture(ws, scene) | texture_ceiling(scene)


def mesh_normals(ws: Path, scene) -> dict:
    """The median and 90th percentile of the angle (degrees) between the workspace's mesh, where it lies within
    0.2 % of the extent of the true surface, and the true surface's normal (recon.eval.surface.normal_angles):
    a bumpy flat face or a rounded edge, which the F-scores hardly count."""
    import trimesh

    from recon.eval.surface import normal_angles
    from recon.products import Published

    mesh = trimesh.load(Published(ws).mesh, process=False)
    vertices = recon.api.model_to_ground_truth(ws, scene.root).apply(np.asarray(mesh.vertices))
    angles = normal_angles(vertices, mesh.faces, scene, float(TAUS[0]) * scene.extent)
    if not len(angles):
        return {}
    return {"mesh_normal_degrees": float(np.median(angles)), "mesh_normal_degrees_p90": float(np.percentile(angles, 90))}


#: figures whose worst scene is the one with the largest value
LOWER_IS_BETTER = ("mesh_normal_degrees", "mesh_normal_degrees_p90")


def summary(rows: list[dict]) -> dict:
    """Mean and worst over the scenes (a failed scene counts as F = 0 and coverage 0)."""
    cols = {f"{k}@{t}": [r[k][f"F@{t}"] if k in r else 0.0 for r in rows] for k in ("fused", "mesh") for t in TAUS}
    cols["coverage"] = [r.get("coverage", 0.0) for r in rows]
    cols["holdout_seen_twice"] = [r["holdout_seen_twice"] for r in rows if "holdout_seen_twice" in r]
    for key in ("mesh_normal_degrees", "mesh_normal_degrees_p90",
                "psnr", "psnr_vertex_colours", "psnr_placed", "psnr_vertex_colours_placed", "true_shape",
                "psnr_true_shape", "psnr_vertex_colours_true_shape", "psnr_ceiling", "psnr_diffuse",
                "psnr_vertex_colours_diffuse"):
        cols[key] = [r[key] for r in rows if key in r]
    for gain, texture, vertex in (("psnr_gain", "psnr", "psnr_vertex_colours"),
                                  ("psnr_gain_placed", "psnr_placed", "psnr_vertex_colours_placed"),
                                  ("psnr_gain_true_shape", "psnr_true_shape", "psnr_vertex_colours_true_shape"),
                                  ("psnr_gain_diffuse", "psnr_diffuse", "psnr_vertex_colours_diffuse")):
        cols[gain] = [r[texture] - r[vertex] for r in rows if texture in r]
    return {"mean": {k: float(np.mean(v)) for k, v in cols.items() if v},
            "worst": {k: float(np.max(v) if k in LOWER_IS_BETTER else np.min(v)) for k, v in cols.items() if v},
            "failed": [r["scene"] for r in rows if "error" in r]}


#: The largest move of one scene's figure that changing ``mvs.seed`` alone made, rounded up (0 -> 1, the 15
#: zoo scenes at 640x480, docs/DECISIONS.md): PatchMatch starts from random planes, so a change to the depth
#: maps that moves a scene by less is not told from chance by one run. Changes after the mvs stage, on
#: the same depth maps, are deterministic.
SEED_SPREAD = {"fused@0.002": 0.0015, "mesh@0.002": 0.004, "psnr": 0.6, "psnr_gain": 0.6, "coverage": 0.013,
               "psnr_placed": 0.6, "psnr_gain_placed": 0.6}
COMPARED = (("fused@0.002", "fusedF.2", ".4f"), ("mesh@0.002", "meshF.2", ".4f"), ("psnr", "texPSNR", ".2f"),
            ("psnr_gain", "tex-vc", ".2f"), ("coverage", "cover", ".4f"), ("psnr_placed", "texPSNRpl", ".2f"),
            ("psnr_gain_placed", "tex-vc.pl", ".2f"))


def compare(before: dict, after: dict) -> None:
    """Print two quality.json results side by side: per scene both have, then mean and worst over those
    scenes, and how many scenes each figure moved up and down, at all and by more than :data:`SEED_SPREAD`."""
    by_name = [{r["scene"]: r for r in run["scenes"]} for run in (before, after)]
    names = [n for n in by_name[1] if n in by_name[0]]
    runs = [[scenes[n] for n in names] for scenes in by_name]
    alone = sorted(set(by_name[0]) ^ set(by_name[1]))
    if alone:
        print(f"left out, in one run only: {', '.join(alone)}")
    rendering = [run.get("texture_rendering", "one ray per pixel") for run in (before, after)]
    if rendering[0] != rendering[1]:
        print(f"the texture PSNRs do not compare: the models were rendered {rendering[0]} before, {rendering[1]} "
              "after (recon.quality_bench.render_as_photographed)")
    print(f"{'scene':<16}" + "".join(f"{label:>18}" for _, label, _ in COMPARED))
    columns = [[summary([r])["mean"] for r in rows] for rows in runs]
    for name, b, a in zip(names, *columns):
        _print_moves(name, b, a)
    for which in ("mean", "worst"):
        _print_moves(f"{which} ({len(names)})", *(summary(rows)[which] for rows in runs))
    for label, steps in (("at all", dict.fromkeys(SEED_SPREAD, 1e-4)), ("by more than the seed does", SEED_SPREAD)):
        counts = []
        for key, name, _ in COMPARED:
            pairs = [(b[key], a[key]) for b, a in zip(*columns) if key in b and key in a]
            up, down = (sum(a > b + steps[key] for b, a in pairs), sum(a < b - steps[key] for b, a in pairs))
            counts.append(f"{name} {up}/{down}")
        print(f"scenes up/down {label}: " + ", ".join(counts))


def _print_moves(label: str, before: dict, after: dict) -> None:
    """One line of :func:`compare`: each compared figure as before -> after ("-" where a run has none)."""
    cells = (" -> ".join("-" if v is None else format(v, fmt) for v in (before.get(key), after.get(key)))
             for key, _, fmt in COMPARED)
    print(f"{label:<16}" + "".join(f"{cell:>18}" for cell in cells))


def print_table(rows: list[dict], summ: dict) -> None:
    stages = [s for s in STAGES if any(s in r.get("seconds", {}) for r in rows)]
    short = {"preprocess": "prep", "features": "feat", "matching": "match", "undistort": "undist",
             "fusion": "fuse", "texture": "tex"}
    head = (f"{'scene':<16}{'reg':>6}{'AUC5':>6}{'dAcc.2':>7}{'dCmp.2':>7}{'fusedF.2':>9}{'maxF':>6}{'fusedF.5':>9}{'meshF.2':>8}{'meshF.5':>8}{'texPSNR':>8}"
            f"{'vcPSNR':>7}{'texPl':>7}{'vcPl':>6}{'vtx/px':>7}{'cover':>7}{'seen2':>7} |{'render':>7}" + "".join(f"{short.get(s, s):>7}" for s in stages) + f"{'total':>8}")
    print(head)
    print("-" * len(head))

    def fig(v, fmt):
        return format(v, fmt) if v is not None else format("-", ">" + fmt.split(".")[0])

    for r in rows:
        f = [r.get(k, {}).get(f"F@{t}") for k in ("fused", "mesh") for t in TAUS]
        reg = f"{r['registered']}/{r['views']}" if "registered" in r else "-"
        secs = r.get("seconds", {})
        depth = r.get("depth", {})
        ceiling = f_ceiling(r["seen_twice"]) if "seen_twice" in r else None
        print(f"{r['scene']:<16}{reg:>6}{fig(r.get('pose_auc@5'), '6.2f')}{fig(depth.get('accuracy@0.002'), '7.3f')}"
              f"{fig(depth.get('completeness@0.002'), '7.3f')}{fig(f[0], '9.3f')}{fig(ceiling, '6.3f')}{fig(f[1], '9.3f')}{fig(f[2], '8.3f')}{fig(f[3], '8.3f')}"
              f"{fig(r.get('psnr'), '8.2f')}{fig(r.get('psnr_vertex_colours'), '7.2f')}{fig(r.get('psnr_placed'), '7.2f')}"
              f"{fig(r.get('psnr_vertex_colours_placed'), '6.2f')}{fig(r.get('vertices_per_pixel'), '7.2f')}"
              f"{fig(r.get('coverage'), '7.3f')}{fig(r.get('holdout_seen_twice'), '7.3f')} |{fig(r.get('render_seconds'), '7.1f')}" + "".join(f"{secs[s]:>7.1f}" if s in secs else f"{'-':>7}" for s in stages)
              + f"{sum(secs.values()):>8.1f}")
        if "error" in r:
            print(f"{'':<16}failed: {r['error']}")
    for which in ("mean", "worst"):
        m = summ[which]
        print(f"{which:<16}{'':>26}{fig(m.get('fused@0.002'), '9.3f')}{'':>6}{fig(m.get('fused@0.005'), '9.3f')}"
              f"{fig(m.get('mesh@0.002'), '8.3f')}{fig(m.get('mesh@0.005'), '8.3f')}{fig(m.get('psnr'), '8.2f')}"
              f"{fig(m.get('psnr_vertex_colours'), '7.2f')}{fig(m.get('psnr_placed'), '7.2f')}"
              f"{fig(m.get('psnr_vertex_colours_placed'), '6.2f')}{'':>7}{fig(m.get('coverage'), '7.3f')}"
              f"{fig(m.get('holdout_seen_twice'), '7.3f')} |")
    for key, views in (("psnr_gain", "at their true poses"), ("psnr_gain_placed", "placed by recon localize"),
                       ("psnr_gain_true_shape", "at their true poses, where the mesh lies within 0.2 % of the surface")):
        if key in summ["mean"]:
            print(f"texture over vertex colours, held-out views {views}: mean {summ['mean'][key]:+.2f} dB, "
                  f"worst {summ['worst'][key]:+.2f} dB")
    by_views = [r for r in rows if "fused_by_views" in r]
    if by_views:
        print("\nfused cloud at 0.2 %: accuracy, completeness, and completeness where 1, 2, 3-4 or 5+ input views "
              "see the surface (share of the observable surface / completeness there)")
        print(f"{'scene':<16}{'acc':>7}{'cmp':>7}" + "".join(f"{label:>16}" for label, _, _ in VIEW_GROUPS))
        for r in by_views:
            groups = r["fused_by_views"]
            cells = (f"{groups[label]['share']:.3f} / {groups[label]['completeness']:.3f}" if label in groups else "-"
                     for label, _, _ in VIEW_GROUPS)
            fused = r.get("fused", {})
            print(f"{r['scene']:<16}{fig(fused.get('accuracy@0.002'), '7.3f')}{fig(fused.get('completeness@0.002'), '7.3f')}"
                  + "".join(f"{cell:>16}" for cell in cells))
    normals = [r for r in rows if "mesh_normal_degrees" in r]
    if normals:
        print("\nthe mesh where it lies within 0.2 % of the true surface: angle to the true surface's normal, degrees "
              "(median / 90th percentile; bumps on a flat face, a rounded edge)")
        for r in normals:
            print(f"{r['scene']:<16}{r['mesh_normal_degrees']:>7.2f}{r['mesh_normal_degrees_p90']:>7.1f}")
        for which in ("mean", "worst"):
            print(f"{which:<16}{summ[which]['mesh_normal_degrees']:>7.2f}{summ[which]['mesh_normal_degrees_p90']:>7.1f}")
    on_shape = [r for r in rows if "psnr_true_shape" in r]
    if on_shape:
        print("\nheld-out views at their true poses, where the mesh lies within 0.2 % of the true surface: its share "
              "of their surface, texture and vertex-colour PSNR there (the rest, the mesh's own errors, costs both alike)")
        print(f"{'scene':<16}{'share':>7}{'texPSNR':>8}{'vcPSNR':>7}{'tex-vc':>7}")
        for r in on_shape:
            print(f"{r['scene']:<16}{r['true_shape']:>7.3f}{r['psnr_true_shape']:>8.2f}"
                  f"{r['psnr_vertex_colours_true_shape']:>7.2f}{r['psnr_true_shape'] - r['psnr_vertex_colours_true_shape']:>+7.2f}")
    glossy = [r for r in rows if "psnr_diffuse" in r and "psnr_ceiling" in r]
    if glossy:
        print("\nscenes with highlights, held-out views at their true poses: the photos against their rendering "
              "without highlights (ceil: what a texture of the true colours on the true shape scores; ceil-vc: the "
              "most any texture can gain over the vertex colours), and the texture and vertex colours against that "
              "rendering")
        print(f"{'scene':<16}{'ceil':>7}{'texPSNR':>8}{'vcPSNR':>7}{'ceil-vc':>8}{'texDif':>7}{'vcDif':>7}{'tex-vc':>7}")
        for r in glossy:
            print(f"{r['scene']:<16}{r['psnr_ceiling']:>7.2f}{r['psnr']:>8.2f}{r['psnr_vertex_colours']:>7.2f}"
                  f"{r['psnr_ceiling'] - r['psnr_vertex_colours']:>+8.2f}{r['psnr_diffuse']:>7.2f}{r['psnr_vertex_colours_diffuse']:>7.2f}"
                  f"{r['psnr_diffuse'] - r['psnr_vertex_colours_diffuse']:>+7.2f}")


def main(argv: list[str] | None = None) -> int:
    from recon.synth.zoo import SCENES

    parser = argparse.ArgumentParser(prog="python -m recon.quality_bench")
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated zoo scenes (default: all)")
    parser.add_argument("--size", default="640x480", help="image size WxH (default 640x480)")
    parser.add_argument("--views", type=int, default=None, help="regular views per scene (default: the scene's own)")
    parser.add_argument("--config", type=Path, default=CONFIG, help="pipeline config (default pipelines/full.yaml)")
    parser.add_argument("-o", "--override", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=REPO / "bench_out")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"),
                        help="print two quality.json results side by side and run nothing")
    args = parser.parse_args(argv)
    if args.compare:
        return _compare_files(*args.compare)
    names = [n.strip() for n in args.scenes.split(",") if n.strip()]
    unknown = [n for n in names if n not in SCENES]
    if unknown:
        print(f"bench: --scenes: unknown zoo scene(s) {', '.join(unknown)} (`recon synth --list` lists them)",
              file=sys.stderr)
        return 2
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"bench: --size {args.size}: give WIDTHxHEIGHT, e.g. 640x480", file=sys.stderr)
        return 2
    print(f"\n== quality: the zoo ({len(names)} scenes, {width}x{height}) through {args.config.name}, "
          "evaluated against ground truth ==", flush=True)
    rows = []
    path = args.out / "quality.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    for name in names:
        rows.append(bench_scene(name, args.out / "quality", args.config, args.override, width, height, args.views))
        print(f"bench: {name} done" + (f" (failed: {rows[-1]['error']})" if "error" in rows[-1] else ""),
              file=sys.stderr, flush=True)
        # written after every scene: an interrupted run keeps the scenes it finished
        path.write_text(json.dumps({"config": str(args.config), "overrides": args.override,
                                    "size": [width, height], "texture_rendering": TEXTURE_RENDERING,
                                    "scenes": rows, "summary": summary(rows)}, indent=1))
    print_table(rows, summary(rows))
    print(f"results: {path}")
    return 0


def _compare_files(before: Path, after: Path) -> int:
    runs = []
    for path in (before, after):
        try:
            runs.append(json.loads(path.read_text()))
        except (OSError, ValueError) as e:
            print(f"bench: --compare: cannot read {path} ({e}); give two quality.json files of "
                  "make bench-quality", file=sys.stderr)
            return 2
        scenes = runs[-1].get("scenes") if isinstance(runs[-1], dict) else None
        if not isinstance(scenes, list) or not all(isinstance(row, dict) and "scene" in row for row in scenes):
            print(f"bench: --compare: {path} holds no zoo results; give a quality.json of "
                  "make bench-quality", file=sys.stderr)
            return 2
    compare(*runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
