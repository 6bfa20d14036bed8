"""The scene zoo: every scene's ground truth checked against its own mesh, at a small size.

Depth is checked by casting each pixel's ray against the written ``gt/mesh.ply`` in the written
cameras: that ties cameras, depth maps and the surface together for every view, hold-out ones too.
"""


import dataclasses

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image

from recon._open3d import open3d
from recon.cli import main
from recon.imaging.masks import load_mask
from recon.synth import load_scene
from recon.synth.effects import Effects, streak
from recon.synth.render import Renderer
from recon.synth.scene import assemble
from recon.synth.shapes import triangulate
from recon.synth.zoo import SCENES, render_zoo, zoo_setup

W, H, VIEWS, HOLDOUT = 160, 120, 6, 2


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("zoo")
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = render_zoo(name, root / name, views=VIEWS, width=W, height=H, holdout=HOLDOUT)
        return cache[name]

    return get


def _raycast(mesh_path, cam):
    """Camera z of each pixel centre's first hit on the mesh (inf = none) and the hit face's normal."""
    o3d = open3d()
    mesh = trimesh.load(mesh_path, process=False, force="mesh")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    vv, uu = np.mgrid[0 : cam.height, 0 : cam.width]
    px = np.column_stack([uu.ravel() + 0.5, vv.ravel() + 0.5])
    # the lens's distortion undone by OpenCV (k1, k2, p1 = p2 = 0), not by the camera's own code
    xy = cv2.undistortPoints(px[:, None], cam.K, np.array([*cam.radial, 0.0, 0.0]), None, None, None,
                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))[:, 0]
    dirs = np.column_stack([xy, np.ones(len(xy))]) @ cam.R  # world directions with camera z = 1
    rays = np.column_stack([np.tile(cam.center, (len(dirs), 1)), dirs]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    normals = hit["primitive_normals"].numpy() @ cam.R.T
    return hit["t_hit"].numpy().reshape(cam.height, cam.width), normals.reshape(cam.height, cam.width, 3)


def test_list_shows_at_least_ten_scenes(capsys):
    assert main(["synth", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) >= 10 and len(lines) == len(SCENES)
    names = [line.split()[0] for line in lines]
    assert names == list(SCENES) and all(len(line.split(maxsplit=1)[1]) > 20 for line in lines)


@pytest.mark.parametrize("name", list(SCENES))
def test_ground_truth_of_every_scene(rendered, name):
    info = rendered(name)
    assert load_scene(info.root) == info and info.name == name
    assert len(info.image_names) == VIEWS and len(info.holdout_names) == HOLDOUT
    cams = {**info.cameras(), **info.cameras(holdout=True)}
    assert set(cams) == {*info.image_names, *info.holdout_names}
    setup = zoo_setup(name)
    seen = 0
    for image_name, cam in cams.items():
        folder = info.images_dir if image_name in info.image_names else info.holdout_images_dir
        with Image.open(folder / image_name) as im:
            assert im.size == (W, H)
        np.testing.assert_allclose(cam.K, [[setup.focal_factor * W, 0, W / 2], [0, setup.focal_factor * W, H / 2],
                                           [0, 0, 1]])
        assert cam.radial == setup.radial
        np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(cam.R) == pytest.approx(1.0)
        depth, normal = info.depth(image_name), info.normal(image_name)
        t, face_normal = _raycast(info.mesh_path, cam)
        valid = depth > 0
        # depth of a pixel = distance along its ray (camera z) to the ground-truth mesh
        np.testing.assert_array_equal(valid, np.isfinite(t))
        np.testing.assert_allclose(depth[valid], t[valid], rtol=1e-4, atol=1e-5)
        # normals: unit, facing the camera, near the hit face's normal (smooth shading on curved parts)
        n = normal[valid]
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
        assert not normal[~valid].any()
        cos = np.abs(np.einsum("ij,ij->i", n, face_normal[valid]))
        assert np.median(cos) > np.cos(np.radians(3.0))
        seen += valid.sum()
    assert seen > 0.1 * W * H * len(cams)  # the scene is in view (the black turntable fills 16 %)
    assert 0 < info.extent <= np.linalg.norm(np.subtract(info.bbox_max, info.bbox_min)) + 1e-6


def test_masks_are_the_objects_projection(rendered):
    info = rendered("masked_object")
    assert info.masked
    obj = trimesh.load(info.object_mesh_path, process=False, force="mesh")
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(obj.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(obj.faces, np.uint32)))
    for names, folder, holdout in ((info.image_names, info.masks_dir, False),
                                   (info.holdout_names, info.holdout_masks_dir, True)):
        cams = info.cameras(holdout=holdout)
        for image_name in names:
            mask = load_mask(folder, image_name, (H, W))
            assert mask is not None and 30 < mask.sum() < 0.5 * W * H
            cam, depth = cams[image_name], info.depth(image_name)
            v, u = np.nonzero(depth > 0)
            pts = (np.column_stack([u + 0.5, v + 0.5, np.ones(len(u))]) @ np.linalg.inv(cam.K).T) * depth[v, u, None]
            world = (pts - cam.t) @ cam.R
            dist = np.full((H, W), np.inf)
            dist[v, u] = scene.compute_distance(o3d.core.Tensor(world.astype(np.float32))).numpy()
            on_object = dist < 1e-4 * info.extent
            assert not (mask & ~on_object).any()  # every masked pixel shows the object
            assert (on_object & ~mask).sum() <= 0.02 * mask.sum()  # ... and the object is masked


def test_transient_object_only_in_some_views_and_not_in_ground_truth(rendered):
    info = rendered("transient_car")
    setup = zoo_setup("transient_car")
    assert 0 < len(info.transient_names) < VIEWS
    clean = Renderer(assemble(setup.parts), setup.background)
    cams = info.cameras()
    for image_name in info.image_names:
        photo = np.asarray(Image.open(info.images_dir / image_name).convert("RGB"), np.float32)
        diff = np.abs(photo - clean.render(cams[image_name])[0]).mean(axis=2)
        cover_path = info.transient_dir / f"{image_name.rsplit('.', 1)[0]}.png"
        if image_name not in info.transient_names:
            assert not cover_path.exists() and np.median(diff) < 3
            continue
        cover = np.asarray(Image.open(cover_path)) > 0
        assert cover.mean() > 0.02
        assert np.median(diff[cover]) > 20  # the car is in the photo ...
        near = np.zeros_like(cover)
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                near |= np.roll(cover, (dy, dx), axis=(0, 1))
        assert np.median(diff[~near]) < 3  # ... and nothing else changed
    assert not info.transient_dir.exists() or len(list(info.transient_dir.iterdir())) == len(info.transient_names)


def test_cli_renders_a_zoo_scene_and_the_seeded_scene(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "z"), "--scene", "turntable_black", "--views", "3", "--width", "96",
                 "--height", "72", "--holdout", "1"]) == 0
    z = load_scene(tmp_path / "z")
    assert (z.name, z.views, z.holdout, z.width) == ("turntable_black", 3, 1, 96)
    assert main(["synth", str(tmp_path / "s"), "--views", "2", "--width", "96", "--height", "72"]) == 0
    s = load_scene(tmp_path / "s")
    assert (s.name, s.views, s.holdout, s.path) == ("", 2, 0, "orbit")
    assert main(["synth", str(tmp_path / "x"), "--scene", "courtyrd"]) == 2
    assert "did you mean 'courtyard'" in capsys.readouterr().err


def test_effects():
    grey = np.full((60, 80, 3), 128, np.uint8)
    vignette = Effects(vignetting=0.4).apply(grey, 0, seed=0).astype(float)
    assert vignette[30, 40].mean() > vignette[0, 0].mean() + 20
    gains = [Effects(exposure_stops=0.7).apply(grey, i, seed=0).mean() for i in range(12)]
    assert max(gains) - min(gains) > 30 and np.std([g / 128 for g in gains]) > 0.1
    noisy = Effects(noise=4.0).apply(grey, 0, seed=0).astype(float)
    assert 3.0 < noisy.std() < 5.0
    assert np.array_equal(Effects(noise=4.0).apply(grey, 3, seed=1), Effects(noise=4.0).apply(grey, 3, seed=1))
    k = streak(5.0, 0.3)
    assert k.sum() == pytest.approx(1.0) and k.shape == (7, 7)
    ys, xs = np.mgrid[0:7, 0:7]
    assert (k * xs).sum() == pytest.approx(3.0, abs=1e-6) and (k * ys).sum() == pytest.approx(3.0, abs=1e-6)


def test_triangulate_concave_polygon():
    poly = np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], float)  # an L, area 5
    tris = triangulate(poly)
    a = poly[tris]
    e1, e2 = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert len(tris) == 4 and area.sum() == pytest.approx(5.0)




def test_a_lens_with_distortion_bends_the_photo(rendered):
    """wide_lens's photos are taken through its barrel distortion: a world point is imaged where OpenCV's
    projection with the lens's coefficients puts it, a corner of the frame well inside the pinhole's."""
    info = rendered("wide_lens")
    k1, k2 = zoo_setup("wide_lens").radial
    assert k1 < 0
    cam = info.cameras()[info.image_names[0]]
    depth = info.depth(info.image_names[0])
    v, u = np.nonzero(depth > 0)
    world = cam.backproject(np.column_stack([u + 0.5, v + 0.5]), depth[v, u])
    uv, _ = cv2.projectPoints(world, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, np.array([k1, k2, 0.0, 0.0]))
    np.testing.assert_allclose(uv[:, 0], np.column_stack([u + 0.5, v + 0.5]), atol=1e-4)
    pinhole = cam.K @ np.array([*cam.rays(np.array([[0.5, 0.5]]))[0]])
    assert np.hypot(*(pinhole[:2] - cam.K[:2, 2])) > np.hypot(*(np.array([0.5, 0.5]) - cam.K[:2, 2])) + 4


def test_glossy_parts_show_a_highlight_that_moves_with_the_view(rendered):
    """glossy's glazed parts add a white highlight to their colour, and only they do; the highlight falls on
    different places from different views (the colour of a point depends on the view)."""
    setup = zoo_setup("glossy")
    info = rendered("glossy")
    shiny = [i for i, p in enumerate(setup.parts) if p.gloss > 0]
    assert shiny and len(shiny) < len(setup.parts)
    glossy, matte = _with_and_without_highlights(setup)
    lit = []
    for cam in info.cameras().values():
        extra = glossy.render(cam, supersample=1)[0].astype(int) - matte.render(cam, supersample=1)[0].astype(int)
        assert (extra >= 0).all()  # a highlight only adds light
        on = extra.max(axis=2) > 0
        assert np.isin(glossy.part_ids(cam)[on], shiny).all()
        lit.append(on)
    assert max(on.sum() for on in lit) > 0.01 * W * H
    assert any((a != b).any() for a, b in zip(lit, lit[1:]))


def _with_and_without_highlights(setup) -> tuple[Renderer, Renderer]:
    """Renderers of ``setup``'s parts as they are and with every part matte."""
    return (Renderer(assemble(setup.parts), setup.background),
            Renderer(assemble([dataclasses.replace(p, gloss=0.0) for p in setup.parts]), setup.background))


def test_a_glossy_scene_ships_its_held_out_views_without_highlights(rendered):
    """What a texture can show of a held-out view of glossy: the view rendered without highlights, written as
    its photo is; the photo is that plus the highlights. A matte scene ships none."""
    glossy, matte = _with_and_without_highlights(zoo_setup("glossy"))
    info = rendered("glossy")
    for name, cam in info.cameras(holdout=True).items():
        diffuse = np.asarray(Image.open(info.holdout_diffuse_dir / name).convert("RGB")).astype(int)
        photo = np.asarray(Image.open(info.holdout_images_dir / name).convert("RGB")).astype(int)
        without = matte.render(cam)[0].astype(int)
        lit = (glossy.render(cam)[0].astype(int) - without).max(axis=2) > 40
        assert np.abs(diffuse - without).mean() < 2  # (JPEG)
        assert (photo - diffuse)[lit].mean() > 30 and np.abs(photo - diffuse)[~lit].mean() < 2
    assert not rendered("classic").holdout_diffuse_dir.exists()
