"""Pictures of a fused map: a PNG with a top view and an oblique view, and open3d's viewer."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from runtime.files import atomic_write_bytes


def _subsample(n: int, max_points: int, seed: int) -> np.ndarray:
    if n <= max_points:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_points, replace=False))


def _oblique(points: np.ndarray, azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic screen coordinates (P,2) and depth (P,) seen from the given azimuth/elevation."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    view = -np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])  # camera -> scene
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(right, view)
    return np.stack([points @ right, points @ up], axis=1), points @ view


def render_views(points: np.ndarray, grey: np.ndarray | None, out_png: str | Path,
                 max_points: int = 200_000, seed: int = 0) -> None:
    """Write a PNG with a top (x-y) view and an oblique view of the map, coloured by height z.

    Args:
        points: (P,3) points in M (gravity-aligned, z up), metres.
        grey: (P,) uint8 grey values that shade the height colours, or None.
        out_png: the PNG file (written atomically).
        max_points: at most this many points are drawn (a seeded random subset).
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    keep = np.isfinite(pts).all(axis=1)
    idx = np.flatnonzero(keep)[_subsample(int(keep.sum()), max_points, seed)]
    pts = pts[idx]
    shade = None if grey is None else 0.55 + 0.45 * np.asarray(grey, np.float64).reshape(-1)[idx] / 255.0
    fig = Figure(figsize=(13, 6), dpi=100)
    FigureCanvasAgg(fig)
    ax_top, ax_obl = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    if len(pts) == 0:
        for ax in (ax_top, ax_obl):
            ax.text(0.5, 0.5, "empty map", ha="center", va="center", transform=ax.transAxes)
    else:
        import matplotlib

        z = pts[:, 2]
        zlo, zhi = np.percentile(z, [2, 98])
        norm = matplotlib.colors.Normalize(zlo, max(zhi, zlo + 1e-6))
        cmap = matplotlib.colormaps["viridis"]
        rgba = cmap(norm(z))
        if shade is not None:
            rgba[:, :3] *= shade[:, None]
        s = float(np.clip(5e4 / len(pts), 0.1, 4.0))
        order = np.argsort(z)  # top view: higher points drawn last
        ax_top.scatter(pts[order, 0], pts[order, 1], c=rgba[order], s=s, linewidths=0, rasterized=True)
        ax_top.set(title="top view (x-y)", xlabel="x [m]", ylabel="y [m]", aspect="equal")
        uv, depth = _oblique(pts - pts.mean(axis=0), azimuth_deg=-60.0, elevation_deg=35.0)
        order = np.argsort(-depth)  # far points first
        ax_obl.scatter(uv[order, 0], uv[order, 1], c=rgba[order], s=s, linewidths=0, rasterized=True)
        ax_obl.set(title="oblique view (azimuth -60°, elevation 35°)", aspect="equal", xticks=[], yticks=[])
        sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=[ax_top, ax_obl], label="height z [m]", shrink=0.8)
    fig.suptitle(f"DAVIO map: {len(pts)} points drawn")
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(Path(out_png), buf.getvalue())


def display_available() -> bool:
    """Whether a window can be opened (X11/Wayland on Linux; assumed elsewhere)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def interactive(points: np.ndarray, grey: np.ndarray | None = None) -> str | None:
    """Open open3d's viewer on the points; returns None when it ran, or why it could not open."""
    if not display_available():
        return "no display (DISPLAY/WAYLAND_DISPLAY unset)"
    try:
        import open3d as o3d
    except (ImportError, OSError) as exc:
        return f"open3d cannot be imported ({exc})"
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if grey is not None:
        g = np.asarray(grey, np.float64).reshape(-1, 1) / 255.0
        pcd.colors = o3d.utility.Vector3dVector(np.repeat(g, 3, axis=1))
    o3d.visualization.draw_geometries([pcd], window_name="DAVIO map")
    return None
