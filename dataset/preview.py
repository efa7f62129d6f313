"""`uavdata show`: a PNG of a bundle's height map and one user's SINR map, its estimated cells hatched."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import Bundle
from uavplace.infra.files import atomic_write_bytes
from uavplace.schemas.provenance import COARSE_MAP, NEAREST_RECEIVER, NOT_RECORDED, STRAIGHT_PATH, WALKED, code_name


def sinr_panel(bundle: Bundle, user: int) -> tuple[np.ma.MaskedArray, int]:
    """What `uavdata show` draws of ``user``'s SINR: the map with dead and blocked cells masked (blocked ones drawn
    apart), and the count of dead cells the UAV may enter (a cell inside a building is not counted as dead)."""
    blocked = bundle.blocked
    return np.ma.masked_array(bundle.sinr_db[user], mask=bundle.dead[user] | blocked), int((bundle.dead[user] & ~blocked).sum())


#: How `uavdata show` marks the cells whose value is known to be estimated, not traced at the cell itself: a hatch
#: per provenance code. "Not recorded" (an export that does not say) is not hatched: it says nothing of the cell,
#: and over a whole map it would hide the colours; the legend gives its share in words.
HATCHES = {STRAIGHT_PATH: "..", WALKED: "////", COARSE_MAP: "xxxx", NEAREST_RECEIVER: "++"}


def estimated_cells(bundle: Bundle, user: int) -> dict[int, np.ndarray]:
    """The cells of ``user``'s map whose value is known to be estimated or partial (``HATCHES``' codes), a mask per
    code present, outside buildings: what `uavdata show` hatches."""
    codes = bundle.provenance[user]
    return {c: m for c in HATCHES if (m := (codes == c) & ~bundle.blocked).any()}


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
    for color, width in (("black", 1.6), ("white", 0.6)):  # a white line on a black halo: seen on dark and on yellow
        ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors=color, linewidths=width)
    fig.colorbar(im, ax=ax, label=f"building height - altitude ({bundle.altitude_m:g} m) [m]")
    ax.set_title(f"{bundle.city}: height map (outlined: blocked, {int(bundle.blocked.sum())} cells)")
    ax = axes[1]
    blocked = bundle.blocked
    sinr, dead_open = sinr_panel(bundle, user)
    cmap = matplotlib.colormaps["magma"].with_extremes(bad="0.75")
    im = ax.imshow(sinr, origin="lower", extent=extent, cmap=cmap)
    shade = matplotlib.colors.ListedColormap(["#4a90c2"])  # blocked cells in a colour magma never takes
    ax.imshow(np.ma.masked_array(blocked, mask=~blocked), origin="lower", extent=extent, cmap=shade, vmin=0, vmax=1)
    fig.colorbar(im, ax=ax, label="SINR [dB] (grey: dead, no path; blue: blocked)")
    marked = estimated_cells(bundle, user)
    handles = []
    with matplotlib.rc_context({"hatch.color": "white", "hatch.linewidth": 0.6}):
        for code, mask in marked.items():
            ax.contourf(
                mask.astype(float), levels=[0.5, 1.5], hatches=[HATCHES[code]], colors="none", origin="lower", extent=extent
            )
            share = 100 * mask.sum() / max(int((~blocked).sum()), 1)
            handles.append(
                matplotlib.patches.Patch(
                    facecolor="0.35", edgecolor="white", hatch=HATCHES[code], label=f"{code_name(code)} ({share:.1f} %)"
                )
            )
    unrecorded = (bundle.provenance[user] == NOT_RECORDED) & ~blocked
    if unrecorded.any():  # said in words, not hatched: the export does not say whether these were traced or estimated
        share = 100 * unrecorded.sum() / max(int((~blocked).sum()), 1)
        handles.append(
            matplotlib.patches.Patch(
                facecolor="none",
                edgecolor="none",
                label=f"not recorded ({share:.1f} %): traced or estimated, the export does not say",
            )
        )
    if handles:
        ax.legend(
            handles=handles,
            loc="upper left",
            fontsize=7,
            framealpha=0.85,
            title="where the values came from (hatched: estimated, not traced at the cell)",
            title_fontsize=7,
        )
    row = bundle.users.iloc[user]
    if np.isfinite(row["x_m"]) and np.isfinite(row["y_m"]):
        ax.plot(row["x_m"], row["y_m"], marker="*", color="cyan", markersize=14, markeredgecolor="black")
    ax.set_title(f"user {user} (t{row['tx_point']:03d}_{row['tx_set_id']:02d}): SINR, {dead_open} dead open cells")
    for ax in axes:
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.suptitle(f"{bundle.city} @ {bundle.version}: {g.num_x} x {g.num_y} cells of {g.spacing_m:g} m", fontsize=10)
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=110)
    plt.close(fig)
    out = Path(out)
    atomic_write_bytes(out, png.getvalue())  # its errors (a full disk) surface here, not inside matplotlib
    return out
