"""A view keeps its sources of an earlier run (recon.mvs.views.select_problems(keep=...)) while they
all still qualify and include its ``reselect_top`` best: its depth map can then be reused."""

from __future__ import annotations

import pycolmap
import pytest

from recon.mvs.bench import prepare_synthetic
from recon.mvs.options import MVSOptions
from recon.mvs.views import select_problems


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    """6 views along a line past the synthetic scene: view i's best sources are i - 1 and i + 1."""
    root = tmp_path_factory.mktemp("kept-sources")
    prepare_synthetic(root, views=6, width=320, height=240, path="line")
    return pycolmap.Reconstruction(root / "dense" / "sparse")


def sources(rec, keep=None, reselect_top=0) -> tuple[str, ...]:
    problems = select_problems(rec, MVSOptions(max_sources=2), keep=keep, reselect_top=reselect_top)
    return next(p.sources for p in problems if p.ref == "view_002.jpg")


def test_kept_sources_stay_unless_a_better_view_ranks_among_the_best(line):
    fresh = sources(line)
    assert set(fresh) == {"view_001.jpg", "view_003.jpg"}
    older = ("view_000.jpg", "view_004.jpg")  # qualify, but score lower than the nearest neighbours
    assert sources(line, {"view_002.jpg": older}) == older
    assert sources(line, {"view_002.jpg": older}, reselect_top=1) == fresh
    half = ("view_001.jpg", "view_004.jpg")
    assert sources(line, {"view_002.jpg": half}, reselect_top=1) == (half if fresh[0] == "view_001.jpg" else fresh)


def test_sources_that_no_longer_qualify_are_chosen_afresh(line):
    fresh = sources(line)
    assert sources(line, {"view_002.jpg": ("view_001.jpg", "gone.jpg")}) == fresh
    assert sources(line, {"view_002.jpg": ("view_000.jpg", "view_001.jpg", "view_003.jpg")}) == fresh  # > max
