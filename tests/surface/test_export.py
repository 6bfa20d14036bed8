import numpy as np
import pytest
import trimesh

from recon.eval.texture import render
from recon.surface.export import read_glb, write_glb, write_obj, write_ply
from recon.surface.texture import texture_mesh


@pytest.fixture(scope="module")
def textured(small_scene):
    mesh = small_scene.gt_mesh.subdivide_to_size(0.3)
    return texture_mesh(mesh, small_scene.images[:6], small_scene.cameras[:6])


def _same_rendering(a, b, cam):
    ra, ma = render(a, cam, 160, 120)
    rb, mb = render(b, cam, 160, 120)
    assert ma.sum() > 5000 and (ma == mb).all()
    assert np.abs(ra - rb)[ma].mean() < 0.01


def _half_size(cam):
    K = cam.K.copy()
    K[:2] /= 2
    return type(cam)(K, cam.R, cam.t, 160, 120)


def test_glb_round_trip(tmp_path, textured, small_scene):
    path = write_glb(textured, tmp_path / "textured.glb")
    z = textured.vertices[:, 2]
    assert np.allclose(trimesh.load(path, force="mesh").bounds[:, 1], [z.min(), z.max()])  # glTF's Y is recon's Z
    loaded = read_glb(path)  # back in recon's frame
    image = loaded.visual.material.baseColorTexture
    assert image.size == (textured.texture.shape[1], textured.texture.shape[0])
    assert np.array_equal(np.asarray(image.convert("RGB")), textured.texture)
    _same_rendering(textured, loaded, _half_size(small_scene.holdout_cameras[0]))


def test_obj_round_trip(tmp_path, textured, small_scene):
    path = write_obj(textured, tmp_path / "textured.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["textured.mtl", "textured.obj", "textured.png"]
    assert "map_Kd textured.png" in (tmp_path / "textured.mtl").read_text()
    loaded = trimesh.load(path, process=False)
    assert np.array_equal(np.asarray(loaded.visual.material.image.convert("RGB")), textured.texture)
    _same_rendering(textured, loaded, _half_size(small_scene.holdout_cameras[1]))


def test_ply_has_vertex_colours(tmp_path, textured):
    loaded = trimesh.load(write_ply(textured, tmp_path / "mesh.ply"), process=False)
    assert len(loaded.faces) == len(textured.faces)
    assert np.array_equal(np.asarray(loaded.visual.vertex_colors)[:, :3], textured.vertex_colors)


def test_glb_and_obj_record_the_georeferenced_frame(tmp_path, textured):
    import json

    from recon.surface.export import frame_record

    georef = {"georeferenced": True, "crs": "EPSG:32633 (WGS 84 / UTM zone 33N): ...",
              "origin": {"lat": 52.5, "lon": 13.4, "alt": 40.0}, "utm": {"used": True, "offset": [391000.0, 5820000.0, 0.0]}}
    frame = frame_record(georef)
    assert frame == {"crs": georef["crs"], "origin_wgs84": georef["origin"], "utm_offset": [391000.0, 5820000.0, 0.0]}
    assert frame_record({"georeferenced": False, "reason": "no GPS"}) is None
    glb = write_glb(textured, tmp_path / "textured.glb", frame).read_bytes()
    header = json.loads(glb[20:20 + int.from_bytes(glb[12:16], "little")])
    assert header["asset"]["extras"]["georeference"] == {**frame, "axes": "glTF Y up: glTF (x, y, z) = frame (x, z, -y)"}
    first = write_obj(textured, tmp_path / "textured.obj", frame).read_text().splitlines()[0]
    assert json.loads(first.removeprefix("# georeference: ")) == frame
    assert len(trimesh.load(tmp_path / "textured.obj", force="mesh").faces) == len(textured.faces)  # still an OBJ
