"""The quality bench's bookkeeping, and (slow) one tiny zoo scene through the whole bench."""

import json

import numpy as np
import pytest

from recon import quality_bench


def _row(scene, fused, mesh, psnr, vc, cover):
    return {"scene": scene, "views": 6, "registered": 6, "fused": {"F@0.002": fused, "F@0.005": fused},
            "mesh": {"F@0.002": mesh, "F@0.005": mesh}, "psnr": psnr, "psnr_vertex_colours": vc, "coverage": cover,
            "seconds": {"mvs": 1.0}}


def test_summary_counts_a_failed_scene_as_zero():
    rows = [_row("a", 0.9, 0.8, 26.0, 22.0, 0.99), _row("b", 0.7, 0.6, 24.0, 23.0, 0.95),
            {"scene": "c", "views": 6, "error": "StageError: sfm: no model"}]
    s = quality_bench.summary(rows)
    assert s["mean"]["fused@0.002"] == pytest.approx((0.9 + 0.7) / 3)
    assert s["worst"]["mesh@0.005"] == 0.0 and s["worst"]["coverage"] == 0.0
    assert s["mean"]["psnr"] == pytest.approx(25.0) and s["worst"]["psnr_gain"] == pytest.approx(1.0)
    assert s["failed"] == ["c"]


def test_unknown_scene_is_refused(capsys):
    assert quality_bench.main(["--scenes", "courtyard,nope"]) == 2
    assert "nope" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_runs_a_tiny_scene_end_to_end(tmp_path, capsys):
    # the demo's scene, 10 views at 320x240 (turntable_black, 10 views at 640x480, registers 2: 36 degrees
    # apart on a black background, its photos share too few features)
    assert quality_bench.main(["--scenes", "classic", "--size", "320x240", "--views", "10",
                               "--out", str(tmp_path)]) == 0
    out = json.loads((tmp_path / "quality.json").read_text())
    row = out["scenes"][0]
    assert "error" not in row, row.get("error")
    assert row["registered"] >= 8 and 0.0 < row["fused"]["F@0.005"] <= 1.0 and 0.0 < row["coverage"] <= 1.0
    assert row["psnr"] > 10 and {"mvs", "texture"} <= set(row["seconds"])
    assert row["placed"] >= 1 and row["psnr_placed"] > 10
    assert 0.0 < row["true_shape"] <= 1.0 and row["psnr_true_shape"] > 10 and row["psnr_vertex_colours_true_shape"] > 10
    assert 0.0 <= row["pose_auc@5"] <= 1.0 and 0.0 < row["depth"]["completeness@0.002"] <= 1.0
    assert 0.0 < row["seen_twice"] <= 1.0
    assert 0.0 < row["mesh_normal_degrees"] < row["mesh_normal_degrees_p90"] < 90.0
    assert sum(g["share"] for g in row["fused_by_views"].values()) == pytest.approx(1.0)
    fused = row["fused"]  # its F-score is the harmonic mean of its accuracy and completeness
    assert fused["F@0.002"] == pytest.approx(2 / (1 / fused["accuracy@0.002"] + 1 / fused["completeness@0.002"]))
    assert "classic" in capsys.readouterr().out


def test_a_rendering_of_an_earlier_scene_definition_is_rendered_again(tmp_path):
    root = tmp_path / "turntable_black" / "scene"
    first = quality_bench.scene_for("turntable_black", root, 80, 60, 3)
    written = first.scene_json.stat().st_mtime_ns
    assert quality_bench.scene_for("turntable_black", root, 80, 60, 3).scene_json.stat().st_mtime_ns == written
    root.with_name("scene.digest").write_text("an earlier definition")
    assert quality_bench.scene_for("turntable_black", root, 80, 60, 3).scene_json.stat().st_mtime_ns != written


def test_fewer_views_leave_less_surface_seen_twice(tmp_path):
    """maxF, the highest fused F a scene allows: the share of its observable surface two views see; and seen2,
    the share of the held-out views' surface two input views see."""
    few = quality_bench.scene_for("turntable_black", tmp_path / "a" / "scene", 80, 60, 3)
    many = quality_bench.scene_for("turntable_black", tmp_path / "b" / "scene", 80, 60, 12)
    few_seen, many_seen = (quality_bench.seen_twice(quality_bench.surface_views(s)[1]) for s in (few, many))
    assert 0.0 < few_seen < many_seen <= 1.0
    assert 0.0 < quality_bench.holdout_seen_twice(few) < quality_bench.holdout_seen_twice(many) <= 1.0
    assert quality_bench.holdout_seen_twice(many) > 0.9  # a full orbit of 12 sees what the held-out views see
    assert quality_bench.f_ceiling(1.0) == 1.0 and quality_bench.f_ceiling(0.8) == pytest.approx(1.6 / 1.8)


def test_the_texture_ceiling_is_measured_where_the_held_out_photos_show_highlights(tmp_path):
    glossy = quality_bench.scene_for("glossy", tmp_path / "glossy" / "scene", 160, 120, 6)
    matte = quality_bench.scene_for("turntable_black", tmp_path / "matte" / "scene", 80, 60, 3)
    assert 15.0 < quality_bench.texture_ceiling(glossy)["psnr_ceiling"] < 40.0  # the highlights cost
    assert quality_bench.texture_ceiling(matte) == {}


def test_completeness_by_views_splits_the_fused_clouds_completeness_by_how_many_views_see_the_surface():
    points = np.column_stack([np.arange(8.0), np.zeros(8), np.zeros(8)])
    counts = np.array([1, 2, 2, 3, 4, 5, 7, 9])
    seen_thrice = points[counts >= 3] + [0.0, 0.04, 0.0]  # within the limit of the surface three views see
    cloud = np.vstack([seen_thrice, [[1.0, 0.5, 0.0]]])  # and one point beyond it, beside a two-view point
    groups = quality_bench.completeness_by_views(points, counts, cloud, limit=0.05)
    assert groups == {"1": {"share": 1 / 8, "completeness": 0.0}, "2": {"share": 2 / 8, "completeness": 0.0},
                      "3-4": {"share": 2 / 8, "completeness": 1.0}, "5+": {"share": 3 / 8, "completeness": 1.0}}
    overall = np.mean([np.min(np.linalg.norm(cloud - p, axis=1)) <= 0.05 for p in points])
    assert sum(g["share"] * g["completeness"] for g in groups.values()) == pytest.approx(overall)
    empty = quality_bench.completeness_by_views(points, counts, np.empty((0, 3)), limit=0.05)
    assert all(g["completeness"] == 0.0 for g in empty.values()) and set(empty) == set(groups)


def test_the_table_prints_maxf_seen2_and_vertex_density_where_they_were_measured(capsys):
    rows = [_row("a", 0.9, 0.8, 26.0, 22.0, 0.99) | {"seen_twice": 0.8, "holdout_seen_twice": 0.987,
                                                    "vertices_per_pixel": 3.87,
                                                    "fused_by_views": {"2": {"share": 0.25, "completeness": 0.3},
                                                                       "5+": {"share": 0.75, "completeness": 0.99}}},
            _row("b", 0.7, 0.6, 24.0, 23.0, 0.95) | {"holdout_seen_twice": 0.961}]
    rows[0]["fused"] |= {"accuracy@0.002": 0.998, "completeness@0.002": 0.815}
    rows[0] |= {"true_shape": 0.914, "psnr_true_shape": 35.39, "psnr_vertex_colours_true_shape": 34.33}
    quality_bench.print_table(rows, quality_bench.summary(rows))
    lines = capsys.readouterr().out.splitlines()
    assert "maxF" in lines[0] and "seen2" in lines[0] and "vtx/px" in lines[0]
    assert "3.87" in next(line for line in lines if line.startswith("a "))
    assert f"{1.6 / 1.8:.3f}" in next(line for line in lines if line.startswith("a "))
    assert "0.987" in next(line for line in lines if line.startswith("a "))
    assert "0.974" in next(line for line in lines if line.startswith("mean"))
    split = lines[next(i for i, line in enumerate(lines) if "where 1, 2, 3-4 or 5+ input views" in line) + 2]
    assert split.split() == ["a", "0.998", "0.815", "-", "0.250", "/", "0.300", "-", "0.750", "/", "0.990"]
    assert not any(line.startswith("b ") for line in lines[lines.index(split):])  # b has no split
    shape = lines[next(i for i, line in enumerate(lines) if "lies within 0.2 % of the true surface:" in line) + 2]
    assert shape.split() == ["a", "0.914", "35.39", "34.33", "+1.06"]
    assert lines[-1] == shape  # b was not measured there
    gain = next(line for line in lines if "where the mesh lies within 0.2 % of the surface" in line)
    assert gain.endswith("mean +1.06 dB, worst +1.06 dB")


def test_the_table_prints_the_texture_ceiling_of_a_scene_with_highlights_only(capsys):
    rows = [_row("a", 0.9, 0.8, 26.11, 24.51, 0.98) | {"psnr_ceiling": 27.07, "psnr_diffuse": 29.5,
                                                      "psnr_vertex_colours_diffuse": 25.0},
            _row("b", 0.7, 0.6, 24.0, 23.0, 0.95)]
    summ = quality_bench.summary(rows)
    assert summ["mean"]["psnr_gain_diffuse"] == pytest.approx(4.5) and summ["mean"]["psnr_ceiling"] == 27.07
    quality_bench.print_table(rows, summ)
    lines = capsys.readouterr().out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("scenes with highlights"))
    assert lines[head + 2].split() == ["a", "27.07", "26.11", "24.51", "+2.56", "29.50", "25.00", "+4.50"]
    assert len(lines) == head + 3  # b has none


def test_compare_prints_both_runs_and_counts_moves_beyond_the_seed(tmp_path, capsys):
    before = {"scenes": [_row("a", 0.90, 0.80, 26.0, 22.0, 0.99), _row("b", 0.70, 0.60, 24.0, 23.0, 0.95),
                         _row("gone", 0.5, 0.5, 20.0, 20.0, 0.9)]}
    after = {"scenes": [_row("a", 0.95, 0.80, 26.1, 22.0, 0.99), _row("b", 0.6995, 0.65, 24.0, 23.0, 0.90)]}
    paths = [tmp_path / "before.json", tmp_path / "after.json"]
    for path, run in zip(paths, (before, after)):
        path.write_text(json.dumps(run))
    assert quality_bench.main(["--compare", *map(str, paths)]) == 0
    out = capsys.readouterr().out
    assert "left out, in one run only: gone" in out
    assert "0.9000 -> 0.9500" in next(line for line in out.splitlines() if line.startswith("a "))
    assert "0.7000 -> 0.7250" in next(line for line in out.splitlines() if line.startswith("mean (2)"))  # mesh
    # b's fused F moved by .0005: a move, but not one beyond what the seed alone does; a's by .05 is
    assert "up/down at all: fusedF.2 1/1, meshF.2 1/0" in out
    assert ("by more than the seed does: fusedF.2 1/0, meshF.2 1/0, texPSNR 0/0, tex-vc 0/0, cover 0/1, "
            "texPSNRpl 0/0, tex-vc.pl 0/0") in out
    assert "do not compare" not in out
    after["texture_rendering"] = quality_bench.TEXTURE_RENDERING  # a run since the bench renders as photographed
    paths[1].write_text(json.dumps(after))
    assert quality_bench.main(["--compare", *map(str, paths)]) == 0
    assert ("the texture PSNRs do not compare: the models were rendered one ray per pixel before, as photographed "
            "after") in capsys.readouterr().out


def test_compare_refuses_a_file_that_is_not_a_bench_result(tmp_path, capsys):
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"points": 3}))
    assert quality_bench.main(["--compare", str(other), str(other)]) == 2
    assert "other.json holds no zoo results" in capsys.readouterr().err


def test_placed_views_are_rendered_through_the_models_camera_with_its_distortion():
    """The rays of a held-out photo placed in the model: a pinhole camera's are those of its K, R, t; with
    distortion, each ray lands back on its pixel's centre through the camera, not where K alone puts it."""
    from types import SimpleNamespace

    import pycolmap

    from recon.surface.raycast import pixel_rays

    R = pycolmap.Rotation3d(np.array([0.1, -0.2, 0.05, 0.97]) / np.linalg.norm([0.1, -0.2, 0.05, 0.97]))
    pose = pycolmap.Rigid3d(R, np.array([0.3, -0.1, 2.0]))
    pinhole = pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48, params=[50.0, 32.0, 24.0, 0.0])
    origins, directions = quality_bench._pixel_grid(quality_bench._photo_rays(pinhole, pose, 64, 48), 64, 48)
    cam = SimpleNamespace(K=pinhole.calibration_matrix(), R=pose.rotation.matrix(), t=pose.translation)
    o, d = pixel_rays(cam, 64, 48)
    assert np.allclose(origins, o) and np.allclose(directions, d)
    distorted = pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48, params=[50.0, 32.0, 24.0, -0.2])
    _, directions = quality_bench._pixel_grid(quality_bench._photo_rays(distorted, pose, 64, 48), 64, 48)
    in_camera = directions.reshape(-1, 3) @ pose.rotation.matrix().T
    back = distorted.img_from_cam(in_camera).reshape(48, 64, 2)
    u, v = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    assert np.allclose(back, np.stack([u, v], -1), atol=1e-6)
    assert np.abs(directions - d).max() > 0.01  # the corners' rays bend away from the pinhole's


def test_vertices_per_pixel_counts_the_vertices_a_view_sees_on_its_surface():
    """A wall 2 m away filling a 40x30 view, sampled at two vertices per pixel across and one down: 2 per
    pixel. Vertices behind it, off its depth by more than the tolerance, or over pixels outside the true
    surface do not count."""
    from recon.eval.groundtruth import Camera

    cam = Camera(K=np.array([[20.0, 0, 20], [0, 20.0, 15], [0, 0, 1]]), R=np.eye(3), t=np.zeros(3), width=40, height=30)
    u, v = np.meshgrid(np.arange(80) / 2 + 0.25, np.arange(30) + 0.5)
    uv = np.column_stack([u.ravel(), v.ravel()])
    wall = cam.backproject(uv, np.full(len(uv), 2.0))
    depth = np.full((30, 40), 2.0)
    everywhere = np.ones((30, 40), bool)
    assert quality_bench.vertices_per_pixel(wall, cam, depth, everywhere, 0.01) == pytest.approx(2.0)
    behind = cam.backproject(uv, np.full(len(uv), 3.0))
    assert quality_bench.vertices_per_pixel(np.vstack([wall, behind]), cam, depth, everywhere, 0.01) == pytest.approx(2.0)
    left_half = everywhere.copy()
    left_half[:, 20:] = False
    assert quality_bench.vertices_per_pixel(wall, cam, depth, left_half, 0.01) == pytest.approx(2.0)
    assert quality_bench.vertices_per_pixel(wall[: len(wall) // 2], cam, depth, everywhere, 0.01) == pytest.approx(1.0)


def test_the_worst_mesh_normal_is_the_largest_angle_and_the_table_prints_them(capsys):
    rows = [_row("a", 0.9, 0.8, 26.0, 22.0, 0.99) | {"mesh_normal_degrees": 1.5, "mesh_normal_degrees_p90": 9.0},
            _row("b", 0.7, 0.6, 24.0, 23.0, 0.95) | {"mesh_normal_degrees": 2.5, "mesh_normal_degrees_p90": 12.0}]
    summ = quality_bench.summary(rows)
    assert summ["mean"]["mesh_normal_degrees"] == pytest.approx(2.0)
    assert summ["worst"]["mesh_normal_degrees"] == 2.5 and summ["worst"]["mesh_normal_degrees_p90"] == 12.0
    assert summ["worst"]["mesh@0.002"] == 0.6  # the F-scores' worst is still the smallest
    quality_bench.print_table(rows, summ)
    lines = capsys.readouterr().out.splitlines()
    head = next(i for i, line in enumerate(lines) if "angle to the true surface's normal" in line)
    assert [line.split() for line in lines[head + 1:head + 5]] == [
        ["a", "1.50", "9.0"], ["b", "2.50", "12.0"], ["mean", "2.00", "10.5"], ["worst", "2.50", "12.0"]]


def test_a_perfect_model_rendered_as_the_held_out_photos_were_matches_them_at_its_silhouette():
    """The held-out photos are anti-aliased at silhouettes (3 x 3 rays there); the bench renders a mesh the same
    way, so a model with the true shape and colours scores as the photo's own renderer does, where one ray per
    pixel loses at every edge pixel. A ray that misses the model shows the background, unless the scene is
    masked and the ray meets a true surface (the table around the masked card): then it is left out."""
    import trimesh

    from recon.eval.groundtruth import Camera
    from recon.eval.texture import masked_psnr, render_rays
    from recon.surface.raycast import scene_of
    from recon.synth.render import Renderer
    from recon.synth.scene import assemble
    from recon.synth.shapes import quad
    from recon.synth.textures import make_texture

    card = quad("card", [-0.5, -0.4, 0], [1, 0, 0], [0, 0.8, 0], make_texture(np.full((64, 64, 3), 210, np.uint8)))
    table = quad("table", [-2, -2, -0.3], [4, 0, 0], [0, 4, 0], make_texture(np.full((64, 64, 3), 40, np.uint8)))
    background = np.array([0.1, 0.2, 0.6], np.float32)
    a = np.radians(17)
    R = np.diag([1.0, -1.0, -1.0]) @ np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    cam = Camera(np.array([[80.0, 0, 40], [0, 80, 30], [0, 0, 1]]), R, -R @ np.array([0.0, 0, 2]), 80, 60)
    rays = quality_bench._true_rays(cam)
    for parts in ([card], [card, table]):
        truth, depth, _ = Renderer(assemble(parts), background).render(cam)
        whole = assemble(parts)
        true_scene = quality_bench.TrueScene(scene_of(whole.vertices, whole.faces), len(parts) > 1, background)
        mesh = trimesh.Trimesh(card.vertices, card.faces, process=False,
                               vertex_colors=np.tile([*truth[30, 40], 255], (4, 1)).astype(np.uint8))
        card_pixels = Renderer(assemble([card]), background).render(cam)[1] > 0
        image, mask, _ = quality_bench.render_as_photographed(mesh, rays, depth, true_scene)
        point, point_mask = render_rays(mesh, *quality_bench._pixel_grid(rays, 80, 60))
        assert np.array_equal(mask, point_mask)
        if len(parts) == 1:
            assert masked_psnr(image, truth, mask & card_pixels) > 50
            assert masked_psnr(point, truth, mask & card_pixels) < 35
        else:  # a model of the masked card alone does not know the table: its edge pixels show the card
            assert np.allclose(image[mask], point[mask])
