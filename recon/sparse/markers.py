"""Printed targets of known size found in the photos, for metric scale: ArUco markers and chessboards.

The user says what is in view (``sfm.aruco``: the markers' dictionary and side; ``sfm.chessboard``:
its inner corners and square); every registered photo is searched (OpenCV: ``ArucoDetector`` with
sub-pixel corners, ``findChessboardCornersSB``), and each target seen in two photos or more becomes
its corners, each observed in those photos, and known distances between corners: a marker's four
sides; a board's rows and columns end to end, (columns - 1) and (rows - 1) squares long (long
distances: a corner's pixel noise is a small part of them).
:func:`recon.sparse.georeference.place` triangulates the corners in the model and fits its scale to
those distances, as it does for scale bars.

Positions are OpenCV's pixel coordinates, the top-left pixel's centre at (0, 0): the convention of
:mod:`recon.sparse.control`, whose triangulation is used.

A marker's corners are where the lines fitted to its sides meet (OpenCV's CORNER_REFINE_APRILTAG):
``cornerSubPix`` (CORNER_REFINE_SUBPIX) pulls a blurred convex corner 0.2 to 0.4 px into the black
square, so markers measured small and the model came out large: on the synthetic marker scene of
``tests/georef/marker_scene.py`` (16 views; markers' sides 10 to 43 px at 320x240, 21 to 86 px at
640x480) the scale was off by +1.80 % and +0.62 % with it, +0.02 % and -0.05 % with the fitted sides.

A board's corner order is ambiguous: the detector may start from either end, as a board turned half
round (or, when square, a quarter round) looks the same; and its exhaustive search sometimes
assembles a board from a partly hidden one. The photos' orders are made to agree through the
model's cameras, and a photo that agrees with no order is left out (:func:`_ordered_boards`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from recon.options import opt
from recon.sparse.control import ControlError, triangulate
from recon.sparse.photos import read_upright

Dictionary = Literal[
    "DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000", "DICT_5X5_50", "DICT_5X5_100",
    "DICT_5X5_250", "DICT_5X5_1000", "DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000",
    "DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10", "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12"]


@dataclass(frozen=True)
class ArucoMarkers:
    """Printed ArUco (or AprilTag) markers, all of one size, for metric scale."""

    dictionary: Dictionary = opt("DICT_4X4_50", "the markers' dictionary (OpenCV's name)")
    size: float = opt(0.0, "side of a marker's black square (the outer edge of its black border), metres; "
                           "0 = no markers", ge=0)

    @property
    def enabled(self) -> bool:
        return self.size > 0

    def describe(self) -> str:
        return f"{self.dictionary} markers of side {self.size:g} m"


@dataclass(frozen=True)
class Chessboard:
    """A printed chessboard for metric scale."""

    columns: int = opt(9, "inner corners (where four squares meet) along a row of the board: a board of 10 x 7 "
                          "squares has 9 columns and 6 rows of them", ge=2)
    rows: int = opt(6, "inner corners along a column of the board", ge=2)
    square: float = opt(0.0, "side of a square, metres; 0 = no chessboard", ge=0)

    @property
    def enabled(self) -> bool:
        return self.square > 0

    def describe(self) -> str:
        return f"a chessboard of {self.columns} x {self.rows} inner corners, squares of {self.square:g} m"


Observation = tuple[str, float, float]  # (photo, x, y)


@dataclass(frozen=True, eq=False)
class Target:
    """One printed target seen in two photos or more."""

    name: str  # "ArUco 7", "chessboard"
    corners: list[list[Observation]]  # per corner, where each photo that sees the target sees it
    edges: list[tuple[int, int, float]]  # (corner, corner, their known distance in metres)


@dataclass(frozen=True, eq=False)
class Found:
    """What the search of the registered photos for one kind of target found."""

    source: str  # what fixed the scale, when these do: "ArUco markers" or "chessboard"
    option: str  # the option that asked for them: "sfm.aruco", "sfm.chessboard"
    what: str  # the targets as the user described them
    hint: str  # the options to check when none is found
    photos: int  # registered photos searched
    photos_with_detections: int
    targets: list[Target]  # those seen in two photos or more

    @property
    def problem(self) -> str | None:
        """Why no target can be used, or None."""
        if self.targets:
            return None
        found, searched = self.photos_with_detections, self.photos
        seen = (f"found in {found} of {searched} photos, but no two of them agree with the model's cameras"
                if self.source == "chessboard" and found >= 2 else
                f"none was seen in 2 or more registered photos (detections in {found} of {searched} photos)")
        return (f"{self.option}: {self.what}: {seen}; the model's scale does not come from them: check "
                f"{self.hint}, and that the targets are whole and sharp in the photos, their sides 20 pixels or more")


Map = Callable[[Callable, list], list]  # runs fn over items, returns the results in order


def search(model, images: Path, options: ArucoMarkers | Chessboard, map_items: Map | None = None) -> Found:
    """Search the registered photos of ``model`` (a pycolmap Reconstruction; the photos under
    ``images`` by their names, in the geometry of the model's cameras) for the targets ``options``
    describes. ``map_items(fn, items)`` runs the detection of each photo (default: one after another)."""
    names = sorted(model.image(i).name for i in model.reg_image_ids())
    run = map_items or (lambda fn, items: [fn(item) for item in items])
    found = run(functools.partial(detect_file, options=options), [images / name for name in names])
    detections = {name: d for name, d in zip(names, found) if d is not None and len(d)}
    if isinstance(options, ArucoMarkers):
        return marker_targets(detections, options, len(names))
    return board_targets(model, detections, options, len(names))


def detect_file(path: Path, options: ArucoMarkers | Chessboard):
    """What :func:`detect_markers` or :func:`detect_chessboard` finds in the photo at ``path``."""
    gray = np.asarray(read_upright(path).convert("L"))
    if isinstance(options, ArucoMarkers):
        return detect_markers(gray, options.dictionary)
    return detect_chessboard(gray, options.columns, options.rows)


def detect_markers(gray: np.ndarray, dictionary: str) -> dict[int, np.ndarray]:
    """Marker id -> its four corners (4, 2) in the 8-bit image ``gray``, in OpenCV's order (clockwise
    from the marker's own top-left corner, so the same corner in every photo), where the lines fitted
    to its sides meet (module doc). An id seen twice in one photo is left out: which copy is which is
    unknown."""
    import cv2

    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), parameters)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return {}
    ids = ids.reshape(-1).tolist()
    return {i: np.asarray(c, float).reshape(4, 2) for i, c in zip(ids, corners) if ids.count(i) == 1}


def detect_chessboard(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """The board's inner corners (columns x rows, 2) in the 8-bit image ``gray``, row by row, or None
    when the whole board is not found."""
    import cv2

    ok, corners = cv2.findChessboardCornersSB(gray, (cols, rows),
                                              flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    return np.asarray(corners, float).reshape(cols * rows, 2) if ok else None


def marker_targets(detections: dict[str, dict[int, np.ndarray]], markers: ArucoMarkers, photos: int) -> Found:
    """The markers seen in two photos or more (``detections``: photo -> marker id -> corners), each
    with its four sides of ``markers.size``; ``photos``: how many were searched."""
    seen: dict[int, list[str]] = {}
    for name in sorted(detections):
        for marker in detections[name]:
            seen.setdefault(marker, []).append(name)
    targets = [Target(f"ArUco {marker}",
                      [[(name, *map(float, detections[name][marker][k])) for name in names] for k in range(4)],
                      [(k, (k + 1) % 4, markers.size) for k in range(4)])
               for marker, names in sorted(seen.items()) if len(names) >= 2]
    return Found("ArUco markers", "sfm.aruco", markers.describe(), "sfm.aruco.dictionary", photos,
                 len(detections), targets)


def board_targets(model, detections: dict[str, np.ndarray], board: Chessboard, photos: int) -> Found:
    """The chessboard, when seen in two photos or more of ``model`` (``detections``: photo -> its
    corners, row by row), with its rows and columns end to end; ``photos``: how many were searched."""
    cols, rows = board.columns, board.rows
    ordered = _ordered_boards(model, detections, cols, rows)
    targets = []
    if len(ordered) >= 2:
        names = sorted(ordered)
        corners = [[(name, *map(float, ordered[name][k])) for name in names] for k in range(cols * rows)]
        edges = ([(r * cols, r * cols + cols - 1, (cols - 1) * board.square) for r in range(rows)]
                 + [(c, (rows - 1) * cols + c, (rows - 1) * board.square) for c in range(cols)])
        targets.append(Target("chessboard", corners, edges))
    return Found("chessboard", "sfm.chessboard", board.describe(),
                 "sfm.chessboard.columns and rows (inner corners, where four squares meet, not squares)", photos,
                 len(detections), targets)


def _ordered_boards(model, detections: dict[str, np.ndarray], cols: int, rows: int) -> dict[str, np.ndarray]:
    """The photos whose board corners agree, each photo's corners in one order. A seed pair: a photo's
    corners as found, and in one of the photos whose cameras are farthest from it, the order whose
    corners triangulate with them with the least median reprojection error, under a quarter of a
    square in both. Each photo's corners are then put in the order nearest the seed's corners
    projected into it, and agree when half of them are within a quarter of a square; the corners
    triangulated from all that agree are projected again, and the photos whose corners are all within
    a quarter of a square of them are kept. A board found where there is none (the exhaustive
    search can assemble one from a partly hidden board) agrees with no other photo. The first seed
    that two photos or more agree with; empty if none."""
    names = sorted(detections)
    centre = {name: model.find_image_with_name(name).projection_center() for name in names}
    for first in names:
        others = sorted((n for n in names if n != first), key=lambda n: -float(np.linalg.norm(centre[n] - centre[first])))
        for second in others[:SEED_TRIES]:
            points = _seed(model, first, second, detections, cols, rows)
            agree = {} if points is None else _agreeing(model, points, detections, cols, rows, np.median)
            if len(agree) < 2:
                continue
            try:
                points = np.array([triangulate(model, [(name, *c[k]) for name, c in agree.items()]).xyz
                                   for k in range(cols * rows)])
            except ControlError:
                continue
            kept = _agreeing(model, points, detections, cols, rows, np.max)
            if len(kept) >= 2:
                return kept
    return {}


#: photos tried as the second of a seed pair for each first photo (the farthest first)
SEED_TRIES = 5


def _seed(model, first: str, second: str, detections: dict[str, np.ndarray], cols: int,
          rows: int) -> np.ndarray | None:
    """The board's corners (N, 3) in the model triangulated from photo ``first``'s corners as found and
    ``second``'s in the order that fits them best, when that fits within a quarter of a square in
    both photos; else None."""
    limit = min(_square_px(detections[first], cols, rows), _square_px(detections[second], cols, rows)) / 4
    best, best_error = None, limit
    for order in board_orders(cols, rows):
        try:
            points = [triangulate(model, [(first, *a), (second, *b)])
                      for a, b in zip(detections[first], detections[second][order])]
        except ControlError:
            continue
        error = float(np.median([p.reprojection_px.max() for p in points]))
        if error < best_error:
            best, best_error = np.array([p.xyz for p in points]), error
    return best


def _agreeing(model, points: np.ndarray, detections: dict[str, np.ndarray], cols: int, rows: int,
              measure: Callable[[np.ndarray], float]) -> dict[str, np.ndarray]:
    """The photos whose board corners, in the order among the board's symmetries nearest (median
    distance) the projections of ``points`` (the board's corners in the model), are within a quarter
    of a square of them by ``measure`` of the distances; each photo's corners in that order."""
    orders = board_orders(cols, rows)
    agree = {}
    for name, corners in detections.items():
        image = model.find_image_with_name(name)
        in_camera = image.cam_from_world() * points
        if (in_camera[:, 2] <= 0).any():
            continue
        projected = np.asarray(model.camera(image.camera_id).img_from_cam(in_camera)) - 0.5  # OpenCV's pixels
        distances = [np.linalg.norm(corners[order] - projected, axis=1) for order in orders]
        best = int(np.argmin([np.median(d) for d in distances]))
        if measure(distances[best]) < _square_px(corners, cols, rows) / 4:
            agree[name] = corners[orders[best]]
    return agree


def _square_px(corners: np.ndarray, cols: int, rows: int) -> float:
    """The median distance between neighbouring corners of a board found in a photo: a square's side
    in pixels."""
    grid = corners.reshape(rows, cols, 2)
    steps = np.concatenate([np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
                            np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()])
    return float(np.median(steps))


def board_orders(cols: int, rows: int) -> list[np.ndarray]:
    """The orders of a board's corners (indices into the detected, row by row) a detector may return
    for the same board: as found, from the other end (half a turn), mirrored along either axis, and
    for a square board each of those transposed (quarter turns)."""
    grid = np.arange(cols * rows).reshape(rows, cols)
    orders = [grid, grid[::-1, ::-1], grid[::-1, :], grid[:, ::-1]]
    if cols == rows:
        orders += [g.T for g in orders]
    return [np.ascontiguousarray(g).reshape(-1) for g in orders]
