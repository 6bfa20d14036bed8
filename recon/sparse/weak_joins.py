"""Where a model holds together by only a few points: groups of photos whose relative poses rest on them.

A walk round a building at eye height meets each corner with one pair of photos 25-30 degrees apart
and a few dozen matches; a photo past the corner sees almost nothing two photos back. The mapper can
still register every photo (the global mapper needs only each pair's geometry), but the facades are
tied to each other by the handful of 3D points those corner pairs share, so a facade can come out
turned or scaled against the rest while every figure of the model looks sound. Measured on the zoo's
walk (29 photos at 512x384, the global mapper, seeds 0-3): one facade turned 3 degrees, pose AUC@5
22-63, at the same point count and mean reprojection error (0.18-0.19 px) as a right model (AUC@5
93); the corners' photo pairs shared 0-14 points in every model, right or bent, against 50-550
between neighbours along a facade. Neither figure can tell a bent model from a right one, but the
joins say where it can bend, and a user can add photos there.

The check: photos are grouped by the points they share, pairwise (two photos sharing at least
``min_points`` points are in one group), then groups that share at least ``min_points`` points
between them are merged, until none are. The default threshold is the incremental mapper's
``abs_pose_min_num_inliers``: a group tied to the rest by fewer points is tied more loosely than any
photo that mapper would register.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Join:
    """Two groups (indices into :attr:`WeakJoins.groups`), the 3D points both see, and the photo pair
    (one photo of each group) that shares the most of them."""

    groups: tuple[int, int]
    shared_points: int
    photos: tuple[str, str]


@dataclass(frozen=True)
class WeakJoins:
    """The model's photos in groups (names, sorted; largest group first) and the joins between groups
    that share any point; one group means no weak join."""

    min_points: int
    groups: list[list[str]]
    joins: list[Join]

    def warning(self) -> str | None:
        """One line for the user, or None where the photos form one group."""
        if len(self.groups) < 2:
            return None
        sizes = ", ".join(str(len(g)) for g in self.groups[:-1]) + f" and {len(self.groups[-1])}"
        ties = ", ".join(f"{a} / {b} share {j.shared_points}" for j in self.joins for a, b in [sorted(j.photos)])
        return (f"the model's photos fall into {len(self.groups)} groups ({sizes} photos; models.json names them) "
                f"that share fewer than {self.min_points} 3D points with each other"
                + (f" (the photo pairs tying them: {ties})" if ties else "")
                + ": their relative poses rest on those few points, so a group may be turned or scaled against "
                "the rest. Take more photos where the groups meet (round corners especially)")

    def to_json(self) -> dict:
        return {"min_points": self.min_points, "groups": self.groups,
                "joins": [{"groups": list(j.groups), "shared_points": j.shared_points, "photos": list(j.photos)}
                          for j in self.joins]}


def weak_joins(rec, min_points: int) -> WeakJoins:
    """The groups of ``rec``'s registered photos (a pycolmap Reconstruction) and their joins. Sparse
    throughout: photos x photos is too large to hold dense for a survey of thousands of photos."""
    from scipy.sparse import csr_matrix, triu
    from scipy.sparse.csgraph import connected_components

    ids = sorted(rec.reg_image_ids())
    index = {image_id: k for k, image_id in enumerate(ids)}
    rows, cols = [], []
    for p, point in enumerate(rec.points3D.values()):
        seen = {index[e.image_id] for e in point.track.elements if e.image_id in index}
        rows += [p] * len(seen)
        cols += seen
    sees = csr_matrix((np.ones(len(rows), np.int32), (rows, cols)), shape=(max(len(rec.points3D), 1), len(ids)))
    shared = _off_diagonal(sees.T @ sees)  # photos x photos: points both see
    _, label = connected_components(shared >= min_points, directed=False)
    while True:
        member = csr_matrix((np.ones(len(ids), np.int32), (np.arange(len(ids)), label)))
        touches = (sees @ member).astype(bool).astype(np.int32)  # points x groups
        between = _off_diagonal(touches.T @ touches)  # groups x groups: points seen from both
        count, merged = connected_components(between >= min_points, directed=False)
        if count == between.shape[0]:
            break
        label = merged[label]
    names = [rec.image(i).name for i in ids]
    members = [np.flatnonzero(label == g) for g in range(between.shape[0])]
    order = sorted(range(len(members)), key=lambda g: (-len(members[g]), min(names[k] for k in members[g])))
    rank = {g: r for r, g in enumerate(order)}
    joins = []
    pairs = triu(between, k=1).tocoo()
    for a, b, n in sorted(zip(pairs.row, pairs.col, pairs.data, strict=True), key=lambda x: (rank[x[0]], rank[x[1]])):
        block = shared[members[a]][:, members[b]].tocoo()
        k = int(np.argmax(block.data))
        joins.append(Join((rank[a], rank[b]), int(n), (names[members[a][block.row[k]]], names[members[b][block.col[k]]])))
    return WeakJoins(min_points, [sorted(names[k] for k in members[g]) for g in order], joins)


def _off_diagonal(matrix):
    matrix = matrix.tocsr()
    matrix.setdiag(0)
    matrix.eliminate_zeros()
    return matrix
