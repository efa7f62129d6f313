"""`uavdata show`: a PNG of a bundle's height map and one user's SINR map."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import Bundle


def render_bundle(bundle: Bundle, user: int, out: str | Path) -> Path:
    """Write a two-panel PNG (height above the UAV altitude; SINR of ``user``) and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not 0 <= user < bundle.num_users:
        raise ValueError(f"user {user} out of range: the bundle has {bundle.num_users} users (0..{bundle.num_users - 1})")
    g = bundle.manifest.grid
    extent = (g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2), constrained_layout=True)
    ax = axes[0]
    im = ax.imshow(bundle.height_rel_m, origin="lower", extent=extent, cmap="viridis")
    ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors="white", linewidths=0.6)
    fig.colorbar(im, ax=ax, label=f"building height - altitude ({bundle.altitude_m:g} m) [m]")
    ax.set_title(f"{bundle.city}: height map (white: blocked, {int(bundle.blocked.sum())} cells)")
    ax = axes[1]
    sinr = np.ma.masked_array(bundle.sinr_db[user], mask=bundle.dead[user])
    cmap = matplotlib.colormaps["magma"].with_extremes(bad="0.75")
    im = ax.imshow(sinr, origin="lower", extent=extent, cmap=cmap)
    ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors="cyan", linewidths=0.5)
    fig.colorbar(im, ax=ax, label="SINR [dB] (grey: dead, no path)")
    row = bundle.users.iloc[user]
    if np.isfinite(row["x_m"]) and np.isfinite(row["y_m"]):
        ax.plot(row["x_m"], row["y_m"], marker="*", color="cyan", markersize=14, markeredgecolor="black")
    ax.set_title(f"user {user} (t{row['tx_point']:03d}_{row['tx_set_id']:02d}): SINR, {int(bundle.dead[user].sum())} dead cells")
    for ax in axes:
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.suptitle(f"{bundle.city} @ {bundle.version}: {g.num_x} x {g.num_y} cells of {g.spacing_m:g} m", fontsize=10)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=110)
    plt.close(fig)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(png.getvalue())  # a plain write: its errors (a full disk) surface here, not inside matplotlib
    return out
