import numpy as np
import pycolmap
import pytest

from recon.mvs.options import MVSOptions
from recon.mvs.views import angle_weight, depths_in_view, select_problems, view_camera
from recon.synth import load_scene


@pytest.fixture(scope="module")
def reconstruction(small_scene):
    return pycolmap.Reconstruction(small_scene / "dense" / "sparse")


def _view(rec: pycolmap.Reconstruction, name: str):
    """The image ``name`` of ``rec`` and its camera as :func:`select_problems` sees it."""
    image = rec.find_image_with_name(name)
    return image, view_camera(image, rec.camera(image.camera_id))


def test_every_view_gets_sources_and_a_depth_range_holding_its_surface(small_scene, reconstruction):
    scene = load_scene(small_scene / "scene")
    problems = select_problems(reconstruction, MVSOptions(max_sources=3))
    assert sorted(p.ref for p in problems) == sorted(scene.image_names)
    for problem in problems:
        assert 1 <= len(problem.sources) <= 3 and problem.ref not in problem.sources
        assert set(problem.cameras) == {problem.ref, *problem.sources}
        truth = scene.depth(problem.ref)
        low, high = np.percentile(truth[truth > 0], [1, 99])
        assert problem.depth_min <= low and high <= problem.depth_max
        assert problem.depth_max < 2 * MVSOptions().far_reach * high  # a reach, not an unbounded range


def test_the_far_bound_reaches_the_points_in_view_that_three_other_photos_agree_on(reconstruction):
    # far ground seen at a grazing angle: other views triangulate it, the view itself matches none of it
    rec = pycolmap.Reconstruction(reconstruction)
    before = {p.ref: p for p in select_problems(rec)}
    image, cam = _view(rec, "view_002.jpg")
    far = 5 * before[image.name].depth_max

    def at(x_cam):  # the world point at camera coordinates x_cam of view_002
        return cam.R.T @ (np.asarray(x_cam, dtype=float) - cam.t)

    def moved(track_length: int, x_cam) -> dict:
        """The problems after a point that view_002 does not observe, with a track of ``track_length``
        photos, is moved to ``x_cam``."""
        moved_rec = pycolmap.Reconstruction(rec)
        pid = next(pid for pid, p in moved_rec.points3D.items() if p.track.length() == track_length
                   and all(e.image_id != image.image_id for e in p.track.elements))
        moved_rec.points3D[pid].xyz = at(x_cam)
        return {p.ref: p for p in select_problems(moved_rec)}

    def range_of(problems):
        return problems[image.name].depth_min, problems[image.name].depth_max

    assert range_of(moved(3, [0.0, 0.0, -far])) == range_of(before)  # behind the camera
    assert range_of(moved(3, [10 * far, 0.0, far])) == range_of(before)  # in front, outside the image
    # on its optical axis: a point two photos matched (a mismatch as often as not) leaves the range as it was
    assert range_of(moved(2, [0.0, 0.0, far])) == range_of(before)
    after = moved(3, [0.0, 0.0, far])[image.name]
    # (its sources see the point a little deeper, and the view reaches as far as they do)
    reach = (1 + MVSOptions().depth_margin) * MVSOptions().far_reach
    assert far * reach <= after.depth_max < 1.01 * far * reach
    assert after.depth_min == before[image.name].depth_min  # the near bound stays on the view's own points


def test_the_far_bound_reaches_far_surface_that_the_sparse_model_does_not_hold(small_scene, reconstruction):
    """With few photos the sparse model holds little of the far ground (the zoo's far_field with 16:
    4 of 487 points beyond 20 m, ranges ending at 24-30 m against 38-42 m). With every sparse point
    deeper than 60 % of a view's true 99th percentile depth removed, the range still holds its surface;
    without the far reach it does not."""
    truth = load_scene(small_scene / "scene").depth("view_002.jpg")
    high = np.percentile(truth[truth > 0], 99)
    rec = pycolmap.Reconstruction(reconstruction)
    _, cam = _view(rec, "view_002.jpg")
    for pid in [pid for pid, p in rec.points3D.items() if cam.R[2] @ p.xyz + cam.t[2] > 0.6 * high]:
        rec.delete_point3D(pid)

    def far_bound(options):
        return {p.ref: p for p in select_problems(rec, options)}["view_002.jpg"].depth_max

    assert far_bound(MVSOptions(far_reach=1.0)) < high <= far_bound(MVSOptions())


def test_points_of_the_view_that_only_two_photos_matched_do_not_set_its_far_bound(reconstruction):
    """Mismatches between two photos of a survey triangulate far below the ground (the zoo's aerial_grid:
    at 9 times its depth in a corner view, whose depth map then held 43 % of its surface, 66 % without
    them); once they exceed 1 % of the view's own points, its 99th percentile took them in."""
    rec = pycolmap.Reconstruction(reconstruction)
    before = {p.ref: p for p in select_problems(rec)}
    image, cam = _view(rec, "view_002.jpg")
    own = [pid for pid, p in rec.points3D.items() if any(e.image_id == image.image_id for e in p.track.elements)]
    pairs = [pid for pid in own if rec.points3D[pid].track.length() == 2]
    assert len(pairs) > 0.01 * len(own)  # more than the 99th percentile leaves out
    centre = -cam.R.T @ cam.t
    for pid in pairs:  # each slid along view_002's ray to 10 times its depth: its pixel there stays
        rec.points3D[pid].xyz = centre + 10 * (rec.points3D[pid].xyz - centre)
    after = {p.ref: p for p in select_problems(rec)}[image.name]
    assert after.depth_max == before[image.name].depth_max


def test_a_view_reaches_as_far_as_its_sources_reach(reconstruction):
    """A view looking along far ground matches none of it, and the sparse points its sources triangulate
    there can lie outside its own frame (the zoo's far_field: 8 of 24 ranges ended short of their
    surface, one at 28 m against 45 m); its range then ends where its sources' ranges end."""
    rec = pycolmap.Reconstruction(reconstruction)
    before = {p.ref: p for p in select_problems(rec)}
    image, mine = _view(rec, "view_002.jpg")
    source, theirs = _view(rec, before[image.name].sources[0])
    far = 5 * before[image.name].depth_max
    # a point at the left or right edge of the source's image, at depth `far`, that view_002 does not see
    candidates = [theirs.R.T @ (far * np.linalg.inv(theirs.K) @ [u, theirs.height / 2, 1.0] - theirs.t)
                  for u in (0.5, theirs.width - 0.5)]
    point = next(x for x in candidates if len(depths_in_view(mine, x[None])) == 0)
    pid = next(pid for pid, p in rec.points3D.items() if p.track.length() == 3
               and all(e.image_id != image.image_id for e in p.track.elements))
    rec.points3D[pid].xyz = point
    after = {p.ref: p for p in select_problems(rec)}
    assert after[source.name].depth_max == pytest.approx(far * (1 + MVSOptions().depth_margin) * MVSOptions().far_reach)
    assert after[image.name].depth_max == after[source.name].depth_max
    assert after[image.name].depth_min == before[image.name].depth_min


def test_the_near_bound_reaches_foreground_that_no_sparse_point_lies_on(small_scene, reconstruction):
    """SfM triangulates little of what stands close in front of a walk's photos (the zoo's walkaround:
    a tree and a bin at 2 m, no sparse point nearer than 5.6 m in those views). With every sparse point
    nearer than twice the view's true near depth removed, its range still starts in front of its
    nearest surface; without the near reach it does not."""
    truth = load_scene(small_scene / "scene").depth("view_002.jpg")
    low = np.percentile(truth[truth > 0], 1)
    rec = pycolmap.Reconstruction(reconstruction)
    image, mine = _view(rec, "view_002.jpg")
    for pid in [pid for pid, p in rec.points3D.items() if (mine.R @ p.xyz + mine.t)[2] < 2 * low]:
        rec.delete_point3D(pid)
    problem = next(p for p in select_problems(rec) if p.ref == image.name)
    assert problem.depth_min <= low
    shallow = next(p for p in select_problems(rec, MVSOptions(near_reach=1.0)) if p.ref == image.name)
    assert shallow.depth_min > low


def test_sources_are_the_neighbours_on_the_path(reconstruction):
    # views move along a line: the best sources of view i are views i - 1 and i + 1
    problems = {p.ref: p for p in select_problems(reconstruction, MVSOptions(max_sources=2))}
    names = sorted(problems)
    for i in range(1, len(names) - 1):
        assert set(problems[names[i]].sources) == {names[i - 1], names[i + 1]}


def _untrack(rec: pycolmap.Reconstruction, image_id: int, point_ids) -> None:
    """Take ``image_id`` out of these points' tracks (as if its features had not been matched)."""
    for pid in point_ids:
        track = pycolmap.Track()
        for element in rec.points3D[pid].track.elements:
            if element.image_id != image_id:
                track.add_element(element.image_id, element.point2D_idx)
            else:
                rec.images[image_id].reset_point3D_for_point2D(element.point2D_idx)
        rec.points3D[pid].track = track


def test_a_view_seeing_points_it_does_not_track_is_a_source_unless_its_own_points_hide_them(reconstruction):
    # a thin sparse model: view_003 tracks only 5 of view_002's points, yet its frame holds all of them
    rec = pycolmap.Reconstruction(reconstruction)
    ids = {im.name: image_id for image_id, im in rec.images.items()}
    ref, other = ids["view_002.jpg"], ids["view_003.jpg"]

    def tracked_by(image_id):
        return {pid for pid, p in rec.points3D.items() if image_id in {e.image_id for e in p.track.elements}}

    shared = sorted(tracked_by(ref) & tracked_by(other))
    assert len(shared) > 20
    hidden = {pid: next(e.point2D_idx for e in rec.points3D[pid].track.elements if e.image_id == other)
              for pid in shared[5:]}
    _untrack(rec, other, hidden)
    assert "view_003.jpg" in {p.ref: p for p in select_problems(rec)}["view_002.jpg"].sources

    # now view_003 has triangulated something at half their depth, where they lie in its image
    image = rec.images[other]
    cam = view_camera(image, rec.camera(image.camera_id))
    centre = -cam.R.T @ cam.t
    for pid, point2D_idx in hidden.items():
        track = pycolmap.Track()
        track.add_element(other, point2D_idx)
        rec.add_point3D(centre + 0.5 * (rec.points3D[pid].xyz - centre), track)
    assert "view_003.jpg" not in {p.ref: p for p in select_problems(rec)}["view_002.jpg"].sources


def test_a_large_minimum_angle_drops_the_nearest_neighbours(reconstruction):
    problems = {p.ref: p for p in select_problems(reconstruction, MVSOptions(min_triangulation_angle=25.0))}
    assert {"view_001.jpg", "view_003.jpg"}.isdisjoint(problems["view_002.jpg"].sources)
    assert select_problems(reconstruction, MVSOptions(min_triangulation_angle=89.0)) == []


def test_angle_weight_peaks_at_five_degrees():
    w = angle_weight(np.array([1.0, 3.0, 5.0, 10.0, 30.0]))
    assert w[2] == pytest.approx(1.0)
    assert w[0] < w[1] < w[2] and w[2] > w[3] > w[4]
    assert w[1] < w[3]  # small angles are penalised faster than large ones


def test_distorted_cameras_are_refused(reconstruction):
    rec = pycolmap.Reconstruction(reconstruction)
    camera = next(iter(rec.cameras.values()))
    camera.model = pycolmap.CameraModelId.SIMPLE_RADIAL
    camera.params = [camera.focal_length_x, camera.principal_point_x, camera.principal_point_y, 0.01]
    with pytest.raises(ValueError, match="pinhole"):
        select_problems(rec)


def test_views_carry_the_ground_normal_of_photos_held_level(reconstruction):
    """The small scene's photos look along a line, held level: the ground faces the photos' mean up, and
    without mvs.ground_normal no view gets one."""
    from recon.mvs.ground_normal import up_direction

    up = up_direction([image.cam_from_world().rotation.matrix() for image in reconstruction.images.values()])
    problems = select_problems(reconstruction)
    assert up is not None and all(np.allclose(p.ground, up) for p in problems)
    assert all(p.ground is None for p in select_problems(reconstruction, MVSOptions(ground_normal=False)))
