"""Unit tests of the texture mapping pieces: rasteriser, bilinear and Lanczos lookups, packing, view
selection, and the evaluation metrics."""

import itertools

import numpy as np
import trimesh
from PIL import Image

from recon.eval.texture import first_hits, masked_psnr, seam_jump
from recon.imaging.pixels import sample_bilinear, sample_lanczos
from recon.surface.texture.atlas import pack
from recon.surface.texture.model import TexturedMesh
from recon.surface.texture.raster import rasterize
from recon.surface.texture.selection import data_costs, energy, select_views


def test_rasterize_covers_triangle_area():
    tri = np.array([[[10.0, 10.0], [90.0, 12.0], [30.0, 70.0]], [[100.0, 100.0], [120.0, 100.0], [100.0, 120.0]]])
    face_map, bary = rasterize(tri, np.array([7, 9]), 128, 128)
    area0 = 0.5 * abs(80 * 60 - 20 * 2)
    assert abs((face_map == 7).sum() - area0) < 0.03 * area0
    assert abs((face_map == 9).sum() - 200) < 15
    ys, xs = np.nonzero(face_map == 7)
    p = np.einsum("nk,kc->nc", bary[ys, xs], tri[0])  # barycentrics give back the texel centres
    assert np.allclose(p, np.stack([xs + 0.5, ys + 0.5], 1), atol=1e-4)


def test_bilinear_is_exact_on_linear_images():
    yy, xx = np.mgrid[:20, :30]
    image = (2.0 * (xx + 0.5) + 3.0 * (yy + 0.5)).astype(np.float32)
    x = np.array([0.5, 3.25, 17.9, 29.5])
    y = np.array([0.5, 7.75, 2.1, 19.5])
    assert np.allclose(sample_bilinear(image, x, y), 2 * x + 3 * y, atol=1e-4)


def test_lanczos_keeps_detail_bilinear_blurs():
    """A stripe pattern four pixels per period, sampled half-way between pixel centres: Lanczos gives it
    back, bilinear halves its contrast. At the centres both give the pixels; any number of lookups."""
    xx = np.arange(64) + 0.5
    pattern = np.sin(2 * np.pi * xx / 4.0 + 0.3)
    image = np.repeat(pattern[None, :, None], 16, 0).repeat(3, 2).astype(np.float32)
    x = np.tile(np.arange(16.0, 48.0) + 0.5, 400)  # 12,800 lookups: more than one row of OpenCV's maps
    y = np.full_like(x, 8.0)
    truth = np.sin(2 * np.pi * (x + 0.5) / 4.0 + 0.3)
    lanczos = sample_lanczos(image, x + 0.5, y)
    bilinear = sample_bilinear(image, x + 0.5, y)
    assert lanczos.shape == (len(x), 3)
    assert np.abs(lanczos[:, 0] - truth).max() < 0.05
    assert np.abs(bilinear[:, 0] - truth).max() > 0.25
    assert np.allclose(sample_lanczos(image[..., 0], x, y), np.sin(2 * np.pi * x / 4.0 + 0.3), atol=1e-5)
    assert sample_lanczos(image, x[:0], y[:0]).shape == (0, 3)


def test_pack_has_no_overlaps():
    rng = np.random.default_rng(0)
    sizes = rng.integers(4, 60, (300, 2))
    pos, width, height = pack(sizes)
    assert width % 4 == 0 and height % 4 == 0
    canvas = np.zeros((height, width), int)
    for (x, y), (w, h) in zip(pos, sizes, strict=True):
        canvas[y:y + h, x:x + w] += 1
    assert canvas.max() == 1 and canvas.sum() == (sizes[:, 0] * sizes[:, 1]).sum()
    assert canvas.sum() / canvas.size > 0.7


def test_selection_matches_brute_force_on_a_small_graph():
    rng = np.random.default_rng(3)
    n, labels = 8, 3
    quality = rng.uniform(0.1, 1.0, (n, labels)).astype(np.float32)
    quality[2, 1] = 0  # view 1 does not see face 2
    pairs = np.array([[i, i + 1] for i in range(n - 1)] + [[0, 4], [2, 6]])
    area = np.ones(n)
    length = np.ones(len(pairs))
    got = select_views(quality, pairs, area, length, smoothness=0.3, cycles=5)
    cost = data_costs(quality, area)
    weights = 0.3 * length
    best = min(energy(cost, np.array(lab), pairs, weights) for lab in itertools.product(range(labels), repeat=n))
    assert got[2] != 1
    assert energy(cost, got, pairs, weights) <= best + 1e-6  # expansion finds the optimum here
    start = quality.argmax(1)
    assert energy(cost, got, pairs, weights) < energy(cost, start, pairs, weights)


def test_selection_leaves_unseen_faces_unlabelled():
    quality = np.array([[1.0, 0.5], [0.0, 0.0], [0.2, 0.9]], np.float32)
    got = select_views(quality, np.array([[0, 1], [1, 2]]), np.ones(3), np.ones(2))
    assert got[1] == -1 and got[0] >= 0 and got[2] >= 0


def test_masked_psnr():
    a = np.full((10, 10, 3), 100.0)
    b = a.copy()
    b[:5] += 10  # only in the masked-out half below
    mask = np.zeros((10, 10), bool)
    mask[5:] = True
    assert masked_psnr(a, b, mask) == float("inf")
    mask[4] = True
    assert np.isclose(masked_psnr(a, b, mask), 10 * np.log10(255**2 / (100 * 10 / 60)))


def _two_chart_square(offset: float) -> TexturedMesh:
    """Two triangles of a unit square, each in its own chart of a smooth texture; the second chart is
    ``offset`` brighter."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    xx = np.tile(np.linspace(50, 150, 64), (64, 1))
    tex = np.concatenate([xx, xx + offset], axis=1)[..., None].repeat(3, 2).astype(np.uint8)
    # both charts map the square onto [4, 60] x [4, 60] texels of their half
    def corner(p, half):
        return [(4 + 56 * p[0] + 64 * half) / 128, 1 - (4 + 56 * (1 - p[1])) / 64]
    uv = np.array([[corner(v[i], 0) for i in f[0]], [corner(v[i], 1) for i in f[1]]])
    return TexturedMesh(v, f, uv, tex, np.array([0, 1]), np.zeros((4, 3), np.uint8))


def test_first_hits_give_the_depth_of_the_nearest_surface_along_each_ray():
    """Rays of camera-frame z = 1 from the origin: a square 2 m away over the left half of the grid, one 3 m
    away behind all of it but the last column; the first hit's distance is the depth of the nearer one."""
    front = trimesh.Trimesh([[-1, -1, 2], [0, -1, 2], [0, 1, 2], [-1, 1, 2]], [[0, 1, 2], [0, 2, 3]])
    back = trimesh.Trimesh([[-1, -1, 3], [0.6, -1, 3], [0.6, 1, 3], [-1, 1, 3]], [[0, 1, 2], [0, 2, 3]])
    both = trimesh.util.concatenate([front, back])
    x, y = np.meshgrid(np.linspace(-0.45, 0.45, 4) / 2, [0.1, -0.1])  # ray columns at x = -0.225 ... 0.225
    directions = np.stack([x, y, np.ones_like(x)], axis=-1)
    t = first_hits(both, np.zeros_like(directions), directions)
    assert np.allclose(t[:, :2], 2.0) and np.allclose(t[:, 2], 3.0) and np.all(np.isinf(t[:, 3]))


def test_seam_jump_measures_the_offset_between_charts():
    assert seam_jump(_two_chart_square(0)) < 0.5
    assert abs(seam_jump(_two_chart_square(40)) - 40) < 1
    # the same through a trimesh with split vertices (as loaded from a file)
    mesh = _two_chart_square(40).to_trimesh()
    assert isinstance(mesh.visual.material.baseColorTexture, Image.Image)
    assert abs(seam_jump(mesh) - 40) < 1
    assert isinstance(mesh, trimesh.Trimesh)
