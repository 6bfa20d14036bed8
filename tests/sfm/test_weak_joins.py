"""Groups of photos tied to the rest of the model by few 3D points (recon.sparse.weak_joins): a right
orbit is one group; cut down to a few points across a split, it is two, and the warning names the
photo pair that ties them."""

import itertools

import pycolmap

from recon.sparse.weak_joins import weak_joins


def _model(sparse_workspace):
    return pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))


def _split(rec):
    """The registered photos' ids in two halves of the orbit (sorted names), and the points that span both."""
    ids = sorted(rec.reg_image_ids(), key=lambda i: rec.image(i).name)
    first = set(ids[: len(ids) // 2])
    spanning = [pid for pid, p in rec.points3D.items()
                if len({e.image_id in first for e in p.track.elements}) == 2]
    return first, spanning


def test_an_orbit_is_one_group(sparse_workspace):
    rec = _model(sparse_workspace)
    joins = weak_joins(rec, 30)
    assert joins.groups == [sorted(rec.image(i).name for i in rec.reg_image_ids())]
    assert joins.joins == [] and joins.warning() is None


def test_few_points_across_a_split_make_two_groups_and_a_warning(sparse_workspace):
    rec = _model(sparse_workspace)
    first, spanning = _split(rec)
    assert len(spanning) > 100
    for pid in spanning[5:]:
        rec.delete_point3D(pid)
    joins = weak_joins(rec, 30)
    names = {rec.image(i).name for i in first}
    rest = {rec.image(i).name for i in rec.reg_image_ids()} - names
    assert {frozenset(g) for g in joins.groups} == {frozenset(names), frozenset(rest)}
    assert len(joins.joins) == 1 and joins.joins[0].shared_points == 5
    a, b = joins.joins[0].photos
    assert (a in names) != (b in names)  # one photo on each side
    warning = joins.warning()
    assert warning.startswith("the model's photos fall into 2 groups") and "share 5" in warning
    assert joins.to_json()["joins"] == [{"groups": [0, 1], "shared_points": 5, "photos": [a, b]}]


def test_groups_tied_by_enough_points_in_all_are_one_though_no_pair_shares_that_many(sparse_workspace):
    rec = _model(sparse_workspace)
    first, spanning = _split(rec)
    kept, per_pair = [], {}
    for pid in spanning:  # keep 40 spanning points, no photo pair sharing more than 10 of them
        images = {e.image_id for e in rec.points3D[pid].track.elements}
        pairs = list(itertools.combinations(sorted(images), 2))
        if len(kept) < 40 and all(per_pair.get(p, 0) < 10 for p in pairs):
            kept.append(pid)
            for p in pairs:
                per_pair[p] = per_pair.get(p, 0) + 1
    assert len(kept) == 40
    for pid in set(spanning) - set(kept):
        rec.delete_point3D(pid)
    assert len(weak_joins(rec, 30).groups) == 1
    assert len(weak_joins(rec, 41).groups) == 2
