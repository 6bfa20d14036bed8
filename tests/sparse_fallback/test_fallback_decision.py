"""The sfm fallback's decisions (issue 16): when the incremental mapper falls short, which mapper's
model is kept and why, and the warning for a model that leaves out more than a quarter of the photos."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import pytest

from recon.sparse.mapping import Attempt, Mapping, choose, left_out_warning, reconstruct, shortfall


def test_shortfall_below_95_percent_or_split():
    assert shortfall(Attempt("incremental", 29, 1, 0.3), 29) is None
    assert shortfall(Attempt("incremental", 28, 1, 0.3), 29) is None  # 96.6 %
    assert shortfall(Attempt("incremental", 27, 1, 0.3), 29) == \
        "the incremental mapper's largest model holds 27 of 29 photos"  # 93.1 %
    assert shortfall(Attempt("incremental", 190, 2, 0.3), 200) == \
        "the incremental mapper's largest model holds 190 of 200 photos, the rest split into 1 more"
    assert shortfall(Attempt("incremental", 0, 0, None), 29) == "the incremental mapper built no model"


def test_global_kept_only_when_it_registers_more_at_a_sound_error():
    incremental = Attempt("incremental", 9, 4, 0.25)
    mapper, why = choose(incremental, Attempt("global", 29, 1, 0.24, 5000), 29)
    assert mapper == "global"
    assert why == ("the incremental mapper's largest model holds 9 of 29 photos, the rest split into 3 more; "
                   "the global mapper's largest model holds 29 of 29 photos")
    mapper, why = choose(incremental, Attempt("global", 29, 1, 2.5, 5000), 29)
    assert mapper == "incremental" and "mean reprojection error of 2.50 px (over 2 px: unsound)" in why
    mapper, why = choose(Attempt("incremental", 0, 0, None), Attempt("global", 3, 1, 0.0, 4), 3)
    assert mapper == "incremental" and why.endswith("model has 4 points (under 100: unsound)")  # seen: 3 far views
    assert choose(incremental, Attempt("global", 9, 2, 0.3, 5000), 29)[0] == "incremental"  # a tie keeps incremental
    mapper, why = choose(incremental, Attempt("global", 0, 0, None), 29)
    assert mapper == "incremental" and why.endswith("the global mapper built no model")


@pytest.mark.parametrize(("registered", "tried", "warned", "tips"), [
    (22, ("incremental", "global"), False, ()),  # 75.9 %: no warning
    (21, ("incremental", "global"), True, ()),  # both mappers ran: neither suggested
    (7, ("incremental",), True, ("sfm.mapper: global",)),  # the fallback was off
    (7, ("global",), True, ("sfm.mapper: incremental",)),
])
def test_left_out_warning(registered, tried, warned, tips):
    mapping = Mapping([], tried[-1], "", [Attempt(m, registered, 1, 0.3) for m in tried])
    warning = left_out_warning(registered, 29, mapping)
    if not warned:
        assert warning is None
        return
    assert warning.startswith(f"only {registered} of 29 photos are in the largest model ({29 - registered} left out)")
    assert "features.max_num_features" in warning
    assert [t for t in ("sfm.mapper: global", "sfm.mapper: incremental") if t in warning] == list(tips)


class _Model:
    def __init__(self, registered: int, error: float = 0.3):
        self.registered, self.error = registered, error

    def num_reg_images(self):
        return self.registered

    def num_points3D(self):
        return 1000 * self.registered


@pytest.fixture
def fake_mappers(monkeypatch, tmp_path):
    """reconstruct() over a database of 29 photos with the mappers replaced by canned model lists."""
    import recon.sparse.mapping as mapping

    made = {"incremental": [_Model(9), _Model(8), _Model(6), _Model(6)], "global": [_Model(29)]}
    calls = []

    def fake_map(mapper, database, images, cfg, seed, start=None, taken_out=None):
        calls.append(mapper)
        return made[mapper]

    monkeypatch.setattr(mapping, "_map", fake_map)
    monkeypatch.setattr(mapping, "capped_mean_error", lambda model: model.error)
    monkeypatch.setattr(mapping, "image_ids", lambda db: {f"view_{k:03d}.jpg": k + 1 for k in range(29)})
    monkeypatch.setattr(mapping, "read_only", lambda database: contextlib.nullcontext())
    return made, calls


@pytest.mark.parametrize(("mapper", "fallback", "expect_calls", "kept"), [
    ("incremental", True, ["incremental", "global"], "global"),
    ("incremental", False, ["incremental"], "incremental"),
    ("global", True, ["global"], "global"),  # the fallback is the incremental mapper's only
])
def test_reconstruct_runs_the_fallback_only_where_asked(fake_mappers, mapper, fallback, expect_calls, kept):
    made, calls = fake_mappers
    cfg = SimpleNamespace(mapper=mapper, mapper_fallback=fallback)
    result = reconstruct("db", "images", cfg, 0)
    assert calls == expect_calls and result.mapper == kept and result.models is made[kept]
    assert [a.mapper for a in result.attempts] == expect_calls
    if not fallback:
        assert result.why == ("sfm.mapper is incremental (the incremental mapper's largest model holds 9 of 29 "
                              "photos, the rest split into 3 more; sfm.mapper_fallback is off)")
