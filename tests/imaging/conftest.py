"""Fixtures shared by the imaging tests."""

import warnings

import pycolmap
import pytest


@pytest.fixture(scope="session")
def sift():
    """pycolmap's CPU SIFT with default options (the extractor recon's features stage uses)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # pycolmap 4.2 prefers FeatureExtractor
        return pycolmap.Sift()
