"""The ground's normal, tested at every pixel by PatchMatch (``mvs.ground_normal``).

PatchMatch finds a pixel's normal by random draws and small perturbations of its neighbours'. Surface seen
at a grazing angle is where that search fails: a normal a few degrees off warps the matching window far
off, so a draw must land close. The ground seen from eye height is mostly such surface, and much of it
only two photos see. Its normal is known before any depth map: photos taken by hand or at eye height are
held about level, so the ground faces the photos' mean up direction (their negated image y axis).

Where the photos agree on an up direction (the length of the mean of their unit up vectors is at least
:data:`MIN_AGREEMENT`), each pixel of the photometric pass also tests its plane turned to face that way,
at its depth, in every sweep; the matching cost decides, as for any candidate. Photos round an object
looking down lean their up vectors in towards it, and round the orbit the lean cancels: the mean's
direction is still the up, its length the cosine of their tilt (zoo orbits 28-40 degrees down: .77-.92).
A nadir survey's photos agree on no up direction, or on a horizontal one (all flown one way), whose plane
the nadir views see edge-on; its ground faces the cameras, where the random search does well. Fitting
planes to the sparse points finds the walls and the table top too, but not the ground of a walk (zoo
walkaround: 15 of its 2,264 sparse points), and testing the walls' normals as well changed nothing there
(docs/DECISIONS.md).

The normal does not key a view's photometric maps (recon.mvs.reuse): photos added later move the mean up
direction a little, and the maps made with the old one are kept as they are.
"""

from __future__ import annotations

import numpy as np

#: the photos' unit up vectors must agree this well (the length of their mean) to give the ground's normal:
#: photos round an orbit looking down up to 60 degrees do
MIN_AGREEMENT = 0.5


def up_direction(rotations: list[np.ndarray]) -> np.ndarray | None:
    """The photos' mean up direction (world frame, unit vector) from their world-to-camera rotations, or
    None where they do not agree on one."""
    if not rotations:
        return None
    mean = np.mean([-np.asarray(R, np.float64)[1] for R in rotations], axis=0)
    length = float(np.linalg.norm(mean))
    return mean / length if length >= MIN_AGREEMENT else None
