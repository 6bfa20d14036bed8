"""Shared fixtures: a small synthetic scene with ground truth, and a sparse run on it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import recon

REPO = Path(__file__).resolve().parents[1]
#: pipelines/sparse.yaml with single-threaded (bit-identical) mapping: tests compare models across runs
SPARSE_TEST = REPO / "tests" / "sparse_test.yaml"


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """A test's captured output with the surrogates of a file name that is not UTF-8 (logged in the test's own
    process) escaped: pytest-xdist's workers send reports as UTF-8, and a lone surrogate stops the worker."""
    report = yield
    report.sections = [(title, text.encode("utf-8", "backslashreplace").decode("utf-8"))
                       for title, text in report.sections]
    return report


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory) -> Path:
    """16 views, 320x240, of the synthetic scene (images/ and gt/)."""
    from recon.synth import render_scene

    out = tmp_path_factory.mktemp("scene") / "small"
    render_scene(out, views=16, width=320, height=240, seed=0)
    return out


@pytest.fixture(scope="session")
def sparse_workspace(small_scene, tmp_path_factory) -> Path:
    """A completed sparse run (ingest .. export) on the small scene; tests must not modify it."""
    ws = tmp_path_factory.mktemp("ws") / "sparse"
    recon.run(SPARSE_TEST, images=str(small_scene / "images"), workspace=str(ws))
    return ws


@pytest.fixture
def copy_workspace(sparse_workspace, tmp_path) -> Path:
    """A private copy of the sparse workspace, free to modify."""
    dest = tmp_path / "ws"
    shutil.copytree(sparse_workspace, dest, symlinks=True)
    return dest


@pytest.fixture(scope="session")
def datasets() -> Path:
    root = recon.datasets_root()
    if not root.is_dir():
        pytest.skip(f"real datasets absent: {root} (set RECON_DATASETS)")
    return root
