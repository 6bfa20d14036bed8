"""No visible seam: exposure steps and blending measured against the environment the views were
rendered from (see pano_eval.seam_jumps for the measure)."""

from __future__ import annotations

import dataclasses

import pano_eval as pe

from recon.panorama import PanoramaOptions, compose


def test_no_visible_seam(ring, ring_panorama):
    truth = pe.ground_truth(ring_panorama, ring.rotations)
    seams = pe.seam_jumps(ring_panorama, truth)
    print(seams)
    assert seams.seam_pixels > 2000  # there are seams to measure (12 photos, ~400 rows each)
    assert seams.jump < 3.0  # grey levels of 255
    assert seams.jump < 1.5 * seams.interior + 0.5  # hardly above the measure's own noise
    assert seams.wrap_jump < 3.0  # the 360 deg wrap is no seam either
    assert seams.gain_spread < 0.02  # views rendered with gains 0.85-1.15 come out within 2 %


def test_the_measure_sees_raw_seams(ring, ring_registration):
    """Without exposure compensation and blending the same measure shows the seams and the gains."""
    raw_opts = dataclasses.replace(PanoramaOptions(), exposure="none", blend="none")
    raw = compose(ring.images, ring_registration, raw_opts)
    seams = pe.seam_jumps(raw, pe.ground_truth(raw, ring.rotations))
    print(seams)
    assert seams.jump > 5.0
    assert seams.gain_spread > 0.2
