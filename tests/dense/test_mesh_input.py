"""The mesh stage's one-line errors name the cloud it meshed: fusion's meshing.ply where fusion made one
(fusion.mesh_reproj_error), else dense/fused.ply."""

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from recon.products import FusedCloud
from recon.stage import StageError
from recon.stages.mesh import Mesh, MeshConfig


def _write_cloud(path, count):
    rng = np.random.default_rng(0)
    trimesh.PointCloud(rng.random((count, 3))).export(path)


@pytest.mark.parametrize("method", ["poisson", "delaunay"])
def test_a_too_small_meshing_cloud_is_named_in_the_error(tmp_path, method):
    _write_cloud(tmp_path / "fused.ply", 500)
    _write_cloud(tmp_path / "meshing.ply", 20)
    ctx = SimpleNamespace(input=lambda product: FusedCloud(tmp_path))
    build = Mesh()._poisson if method == "poisson" else Mesh()._delaunay
    with pytest.raises(StageError, match=r"^mesh: fusion's meshing\.ply \(.*meshing\.ply\) has too few"):
        build(ctx, MeshConfig(method=method))


def test_without_a_meshing_cloud_the_error_names_dense_fused_ply(tmp_path):
    _write_cloud(tmp_path / "fused.ply", 20)
    ctx = SimpleNamespace(input=lambda product: FusedCloud(tmp_path))
    with pytest.raises(StageError, match=r"^mesh: dense/fused\.ply has too few oriented points"):
        Mesh()._poisson(ctx, MeshConfig())
