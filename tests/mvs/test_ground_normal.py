"""The ground's normal from the photos' up direction (recon.mvs.ground_normal)."""

import numpy as np
from scipy.spatial.transform import Rotation

from recon.mvs.ground_normal import up_direction


def _level_photo(yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """World-to-camera rotation of a photo held level (image y pointing down the world's -z), looking
    horizontally at ``yaw_deg``, tilted down by ``pitch_deg``."""
    # camera axes in the world: x right, y down, z forward
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(forward, right)
    return np.stack([right, down, forward])  # rows: the camera axes, so R @ X gives camera coordinates


def test_photos_held_level_give_the_worlds_up():
    rotations = [_level_photo(yaw, pitch) for yaw, pitch in zip(range(0, 360, 30), [0, 5, -5, 10] * 3)]
    up = up_direction(rotations)
    assert up is not None and np.degrees(np.arccos(up @ [0.0, 0.0, 1.0])) < 0.5


def test_an_orbit_looking_down_still_gives_the_up_of_its_photos():
    """Photos round an object, each looking 40 degrees down: their up vectors lean in towards the
    object by 40 degrees, and round the orbit the lean cancels out."""
    up = up_direction([_level_photo(yaw, 40.0) for yaw in range(0, 360, 15)])
    assert up is not None and np.degrees(np.arccos(up @ [0.0, 0.0, 1.0])) < 0.5


def test_photos_that_do_not_agree_on_an_up_direction_give_none():
    """A nadir survey flown back and forth: each photo's image y lies in the ground plane, half of them
    one way and half the other."""
    down = Rotation.from_euler("x", 180, degrees=True).as_matrix()  # looking straight down
    turned = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    rotations = [down, down @ turned] * 4
    assert up_direction(rotations) is None
    assert up_direction([]) is None
