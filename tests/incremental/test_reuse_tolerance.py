"""When a stored depth map stands for one made now (recon.mvs.reuse): cameras within a tolerance in
working pixels, relative to the map's view, through the undistorted and the photo's own camera, and
depth ranges covered."""

from __future__ import annotations

import numpy as np
import pycolmap

from recon.mvs.reuse import camera_record, camera_shift, reusable
from recon.mvs.views import ViewCamera

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])


def view(t=(0.0, 0.0, 0.0), k=K, size=(320, 240), name="a.png") -> ViewCamera:
    return ViewCamera(name, np.asarray(k, float), np.eye(3), np.asarray(t, float), *size)


def shift(old, new, depth_range=(2.0, 4.0), max_image_size=320, old_ref=None, new_ref=None) -> float:
    """The shift of camera ``old`` -> ``new`` relative to a reference that stays put (default: itself)."""
    return camera_shift(old_ref or old, new_ref or new, old, new, depth_range, max_image_size)


def photo(k1=0.0):
    return pycolmap.Camera(model="SIMPLE_RADIAL", width=320, height=240, params=[300.0, 160.0, 120.0, k1])


def test_a_source_moved_sideways_shifts_pixels_by_focal_times_move_over_depth():
    ref = camera_record(view())
    old, new = camera_record(view(name="b.png")), camera_record(view(t=(0.01, 0, 0), name="b.png"))
    # at depth 2 a 0.01 move is 300 * 0.01 / 2 = 1.5 px at full size; the working size halves it
    assert np.isclose(shift(old, new, old_ref=ref, new_ref=ref), 1.5)
    assert np.isclose(shift(old, new, max_image_size=160, old_ref=ref, new_ref=ref), 0.75)
    assert shift(old, old, old_ref=ref, new_ref=ref) < 1e-9


def test_only_relative_motion_counts():
    """A view and its source moved together: the map, in the view's frame, is still right."""
    moved = (0.3, -0.1, 0.2)
    assert shift(camera_record(view(name="b.png")), camera_record(view(t=moved, name="b.png")),
                 old_ref=camera_record(view()), new_ref=camera_record(view(t=moved))) < 1e-9


def test_a_forward_move_is_seen_at_the_corners():
    ref = camera_record(view())
    moved = shift(camera_record(view(name="b.png")), camera_record(view(t=(0, 0, 0.02), name="b.png")),
                  old_ref=ref, new_ref=ref)
    assert 0.9 < moved < 2.0  # corner 200 px off-centre: 200 * 0.02 / 2 ~ 2 px, less the ray's own change


def test_a_focal_change_of_the_view_itself_counts():
    k = K.copy()
    k[0, 0] = k[1, 1] = 301.0
    assert 0.5 < shift(camera_record(view()), camera_record(view(k=k))) < 0.7  # 200 px off-centre * 1/300


def test_a_distortion_change_is_seen_through_the_photo_camera():
    """Same pinhole camera, same pose: only the photo's lens model changed, so the undistorted image
    the map was matched on shows other content."""
    old = camera_record(view(), photo(0.0))
    assert shift(old, camera_record(view(), photo(0.0))) < 1e-9
    assert shift(old, camera_record(view(), photo(0.02))) > 0.5
    assert shift(old, camera_record(view(), photo(1e-5))) < 0.01


def test_other_sizes_are_never_the_same_camera():
    assert shift(camera_record(view()), camera_record(view(size=(322, 240)))) == np.inf
    assert shift(camera_record(view()), camera_record(view(), photo())) == np.inf


def meta(t=(0.0, 0.0, 0.0), near=2.0, far=4.0) -> dict:
    """One view and one source (moved by ``t``), searched from ``near`` to ``far``."""
    cameras = {"a.png": camera_record(view()), "b.png": camera_record(view(t=(0.5 + t[0], t[1], t[2]), name="b.png"))}
    return {"parts": [{"ref": "a.png", "cameras": cameras, "range": [near, far]}]}


def test_reusable_within_the_tolerance_and_when_the_range_covers_the_points():
    assert reusable(meta(), meta(t=(0.001, 0, 0)), 0.25, 0.25, 320)  # 0.15 px
    assert not reusable(meta(), meta(t=(0.01, 0, 0)), 0.25, 0.25, 320)  # 1.5 px
    # the stored search 2..4 covers points at 2.4 / 1.25 .. 3.3 * 1.25 (a range of 1.92..4.125 now)
    assert reusable(meta(), meta(near=1.92, far=4.125), 0.25, 0.25, 320)
    assert not reusable(meta(), meta(near=1.5, far=4.0), 0.25, 0.25, 320)  # points now nearer than searched
    assert not reusable(meta(), meta(far=6.0), 0.25, 0.25, 320)
    assert not reusable(None, meta(), 0.25, 0.25, 320)
    other = meta()
    other["parts"][0]["cameras"]["c.png"] = other["parts"][0]["cameras"]["b.png"]
    assert not reusable(meta(), other, 0.25, 0.25, 320)  # other views
    assert not reusable(meta(), {"parts": meta()["parts"] * 2}, 0.25, 0.25, 320)

