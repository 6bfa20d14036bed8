"""The report's figures as PNG bytes: matplotlib (Agg, no pyplot state) and Pillow for map thumbnails."""

from __future__ import annotations

import io

import numpy as np

REGISTERED, UNREGISTERED = "#3b7dd8", "#d8463b"


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def pair_matrix(pairs: np.ndarray, names: list[str]) -> bytes:
    """Verified inlier matches of every photo pair (log colour scale; white = none)."""
    from matplotlib.colors import LogNorm

    n = len(names)
    side = float(np.clip(3 + 0.12 * n, 4.5, 10))
    fig = _figure(side + 1.2, side)
    ax = fig.add_subplot()
    shown = np.ma.masked_less_equal(pairs.astype(float), 0)
    top = max(float(pairs.max()), 2.0) if pairs.size else 2.0
    im = ax.imshow(shown, cmap="viridis", norm=LogNorm(vmin=1, vmax=top), interpolation="nearest")
    fig.colorbar(im, ax=ax, label="verified matches")
    if n <= 40:
        labels = [name if len(name) <= 18 else "…" + name[-17:] for name in names]
        ax.set_xticks(range(n), labels, rotation=90, fontsize=6)
        ax.set_yticks(range(n), labels, fontsize=6)
    else:
        ax.set_xlabel("photo index")
        ax.set_ylabel("photo index")
    ax.set_title(f"Pair matches ({int((pairs > 0).sum() // 2)} verified pairs of {n * (n - 1) // 2})")
    return _png(fig)


def track_lengths(lengths: np.ndarray) -> bytes:
    fig = _figure(5.5, 3.4)
    ax = fig.add_subplot()
    if len(lengths):
        top = int(lengths.max())
        ax.hist(lengths, bins=np.arange(1.5, top + 1.5, 1.0), color=REGISTERED)
        ax.set_title(f"Track length: {len(lengths)} points, mean {lengths.mean():.2f} photos")
    else:
        ax.set_title("Track length: no points")
    ax.set_xlabel("photos seeing the point")
    ax.set_ylabel("points")
    return _png(fig)


def reprojection_errors(errors: np.ndarray, mean: float) -> bytes:
    """Histogram of the points' reprojection errors (each point's mean over its track) and their ``mean``."""
    fig = _figure(5.5, 3.4)
    ax = fig.add_subplot()
    if len(errors):
        top = float(np.percentile(errors, 99.5)) or 1.0
        ax.hist(np.clip(errors, 0, top), bins=50, range=(0, top), color=REGISTERED)
        ax.axvline(mean, color="k", lw=1, ls="--", label=f"mean {mean:.3f} px")
        ax.legend()
        ax.set_title(f"Reprojection error: {len(errors)} points, median {np.median(errors):.3f} px")
    else:
        ax.set_title("Reprojection error: no points")
    ax.set_xlabel("pixels (mean over the photos seeing the point)")
    ax.set_ylabel("points")
    return _png(fig)


def per_image(names: list[str], keypoints: list[int], matches: list[int], errors: list[float | None],
              registered: list[bool]) -> bytes:
    """Keypoints, verified matches and mean reprojection error of each photo (red: not registered)."""
    n = len(names)
    fig = _figure(float(np.clip(2 + 0.16 * n, 6, 16)), 6.5)
    axes = fig.subplots(3, 1, sharex=True)
    colours = [REGISTERED if r else UNREGISTERED for r in registered]
    x = np.arange(n)
    axes[0].bar(x, keypoints, color=colours)
    axes[0].set_ylabel("keypoints")
    axes[1].bar(x, matches, color=colours)
    axes[1].set_ylabel("verified matches")
    axes[2].bar(x, [e if e is not None else 0.0 for e in errors], color=colours)
    axes[2].set_ylabel("reproj. error (px)")
    if n <= 60:
        axes[2].set_xticks(x, names, rotation=90, fontsize=6)
    else:
        axes[2].set_xlabel("photo index")
    axes[0].set_title(f"Per photo ({sum(registered)} of {n} registered; red = not registered)")
    return _png(fig)


def scene_view(points: np.ndarray, colors: np.ndarray, centers: np.ndarray, directions: np.ndarray,
               axes: np.ndarray, title: str, labels: tuple[str, str]) -> bytes:
    """Points and cameras projected onto the plane of the two world ``axes`` (2 x 3, orthonormal)."""
    fig = _figure(5.5, 5.0)
    ax = fig.add_subplot()
    p = points @ axes.T
    c = centers @ axes.T
    if len(p):
        ax.scatter(p[:, 0], p[:, 1], s=1.5, c=colors / 255.0, linewidths=0)
    if len(c):
        extent = np.ptp(np.vstack([p, c]) if len(p) else c, axis=0).max() or 1.0
        d = directions @ axes.T * 0.06 * extent
        ax.quiver(c[:, 0], c[:, 1], d[:, 0], d[:, 1], color=UNREGISTERED, angles="xy", scale_units="xy",
                  scale=1, width=0.004)
        ax.scatter(c[:, 0], c[:, 1], s=12, color=UNREGISTERED, label=f"{len(c)} cameras")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title)
    return _png(fig)


def pose_figures(poses: dict) -> bytes:
    """Pose AUC at 1, 3 and 5 degrees against ground truth."""
    keys = [k for k in ("auc@1", "auc@3", "auc@5") if k in poses]
    fig = _figure(4.5, 3.2)
    ax = fig.add_subplot()
    values = [poses[k] for k in keys]
    ax.bar(keys, values, color=REGISTERED)
    for i, v in enumerate(values):
        ax.text(i, v + 1, f"{v:.1f}", ha="center", fontsize=9)
    ax.set_ylim(0, 105)
    ax.set_ylabel("AUC (%)")
    ax.set_title(f"Relative pose accuracy ({poses.get('registered')}/{poses.get('total')} registered)")
    return _png(fig)


def depth_thumbnail(depth: np.ndarray, width: int = 240) -> bytes:
    """A depth map coloured near-to-far (turbo), pixels without depth black."""
    from matplotlib import colormaps

    valid = depth > 0
    rgb = np.zeros(depth.shape + (3,), np.uint8)
    if valid.any():
        lo, hi = np.percentile(depth[valid], [2, 98])
        scaled = np.clip((depth - lo) / max(hi - lo, 1e-12), 0, 1)
        rgb = (colormaps["turbo"](scaled)[..., :3] * 255).astype(np.uint8)
        rgb[~valid] = 0
    return _thumbnail(rgb, width)


def normal_thumbnail(normal: np.ndarray, width: int = 240) -> bytes:
    """A normal map as colour: (n + 1) / 2, x right, y down, pixels without a normal black."""
    valid = np.linalg.norm(normal, axis=2) > 0
    rgb = ((np.clip(normal, -1, 1) + 1) * 127.5).astype(np.uint8)
    rgb[~valid] = 0
    return _thumbnail(rgb, width)


def _thumbnail(rgb: np.ndarray, width: int) -> bytes:
    from PIL import Image

    image = Image.fromarray(rgb)
    if image.width > width:
        image = image.resize((width, max(1, round(image.height * width / image.width))), Image.Resampling.BOX)
    buf = io.BytesIO()
    image.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def enu_map(cameras: np.ndarray, photos: list[dict], gcps: list[dict]) -> bytes:
    """A map of a georeferenced model seen from above, in East-North metres: the cameras, each photo's
    GPS position joined to its camera (outliers red), the GCPs' surveyed positions (triangles) and
    where the model has them (crosses)."""
    fig = _figure(6.5, 5.5)
    ax = fig.add_subplot()
    if len(cameras):
        ax.scatter(cameras[:, 0], cameras[:, 1], s=10, color=REGISTERED, label="cameras", zorder=3)
    for photo in photos:
        (ge, gn, _), (ce, cn, _) = photo["gps_enu"], photo["camera_enu"]
        colour = "#888888" if photo["inlier"] else UNREGISTERED
        ax.plot([ge, ce], [gn, cn], color=colour, linewidth=0.8, zorder=2)
    if photos:
        gps = np.array([p["gps_enu"] for p in photos])
        bad = np.array([not p["inlier"] for p in photos])
        ax.scatter(gps[~bad, 0], gps[~bad, 1], s=14, facecolors="none", edgecolors="#444444", label="GPS", zorder=2)
        if bad.any():
            ax.scatter(gps[bad, 0], gps[bad, 1], s=18, color=UNREGISTERED, label="GPS outliers", zorder=2)
    if gcps:
        target = np.array([g["target_enu"] for g in gcps])
        found = np.array([g["model_enu"] for g in gcps])
        ax.scatter(target[:, 0], target[:, 1], marker="^", s=40, color="#2a9d4b", label="GCPs (surveyed)", zorder=4)
        ax.scatter(found[:, 0], found[:, 1], marker="x", s=30, color="#111111", label="GCPs in the model", zorder=5)
        for g in gcps:
            ax.annotate(g["name"], g["target_enu"][:2], fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(True, linewidth=0.3)
    ax.legend(fontsize=7, loc="best")
    ax.set_title("Seen from above (local East-North-Up metres)")
    return _png(fig)
