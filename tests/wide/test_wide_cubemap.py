"""360-degree photos to cube-map faces for the dense stages: the faces are the pinhole views a camera
at the panorama's pose would take, and the model's points keep their tracks."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest
from PIL import Image

from recon.eval.groundtruth import Camera
from recon.mvs.cubemap import FACES, face_name, write_cubemap_workspace
from recon.synth.render import Renderer
from recon.synth.room import build_room
from recon.synth.wide import load_views, range_points, render_room_walk


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A model of three rendered panoramas at their true poses with 300 true surface points, and its
    cube-map workspace."""
    root = tmp_path_factory.mktemp("cube")
    scene = render_room_walk(root / "room", views=3, width=320, height=160)
    views = load_views(scene.root)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="EQUIRECTANGULAR", width=320, height=160,
                                                    params=[320.0, 160.0], camera_id=1))
    first = scene.image_names[0]
    pts = range_points(np.load(scene.depth_dir / "pano_000.npy"), views[first])
    pts = pts[np.random.default_rng(0).choice(len(pts), 300, replace=False)]
    tracks = []
    for image_id, name in enumerate(scene.image_names, start=1):
        v = views[name]
        uv = v.colmap().img_from_cam(pts @ v.R.T + v.t)
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=name, camera_id=1, image_id=image_id,
                           points2D=pycolmap.Point2DList([pycolmap.Point2D(xy) for xy in uv])),
            pycolmap.Rigid3d(pycolmap.Rotation3d(v.R), v.t))
        tracks.append(image_id)
    for k, X in enumerate(pts):
        pid = rec.add_point3D(X, pycolmap.Track(), np.zeros(3, np.uint8))
        for image_id in tracks:
            rec.add_observation(pid, pycolmap.TrackElement(image_id, k))
    (root / "model").mkdir()
    rec.write(str(root / "model"))
    summary = write_cubemap_workspace(root / "model", scene.images_dir, root / "dense")
    return scene, views, root / "dense", summary


def test_faces_are_the_pinhole_views_at_the_panoramas_poses(workspace):
    scene, views, dense, summary = workspace
    assert summary == {"images": 18, "panoramas": 3, "size": "102x102"}  # 320 / pi
    faces = pycolmap.Reconstruction(str(dense / "sparse"))
    renderer = Renderer(build_room(0))
    errors = []
    for name, view in views.items():
        for face in FACES:
            image = faces.find_image_with_name(face_name(name, face))
            cam = faces.cameras[image.camera_id]
            pose = image.cam_from_world()
            np.testing.assert_allclose(pose.rotation.matrix(), np.array(FACES[face]) @ view.R, atol=1e-9)
            np.testing.assert_allclose(pose.translation, np.array(FACES[face]) @ view.t, atol=1e-9)
            truth, _, _ = renderer.render(Camera(cam.calibration_matrix(), pose.rotation.matrix(),
                                                 np.asarray(pose.translation), cam.width, cam.height))
            got = np.asarray(Image.open(dense / "images" / face_name(name, face)), dtype=float)
            errors.append(np.abs(got - truth).mean())
    # resampled from a 320-pixel panorama and JPEG'd twice: a few levels; a face turned the wrong way
    # or shifted by a pixel differs by tens
    assert max(errors) < 8.0, errors


def test_points_keep_their_tracks_in_the_faces(workspace):
    _, _, dense, _ = workspace
    faces = pycolmap.Reconstruction(str(dense / "sparse"))
    assert faces.num_points3D() == 300
    assert faces.compute_num_observations() == 900  # every panorama observation, in exactly one face
    for point in faces.points3D.values():
        for el in point.track.elements:
            image = faces.image(el.image_id)
            x = image.cam_from_world() * point.xyz
            uv = faces.cameras[image.camera_id].img_from_cam(x[None])[0]
            assert np.allclose(uv, image.points2D[el.point2D_idx].xy, atol=1e-6)
    cfg = (dense / "stereo" / "patch-match.cfg").read_text().split("\n")
    assert cfg[:2] == ["pano_000_front.jpg", "__auto__, 20"] and len(cfg) == 37
