"""A physics check: a single conducting knife edge in free space, against ITU-R P.526.

``write_knife_edge_scene`` writes the scene (a conducting screen, its only free edge on top, no
ground) and returns its job: the user 50 m in front of the screen at 1.5 m, the receivers' plane
at 10 m behind it; ``BEHIND_M`` are the checked distances behind the screen (``points`` places
receivers there), ``EXACT_CONFIG`` the exact-path settings, and ``p526_path_gain_db`` gives what
P.526's single knife-edge loss predicts there.
Used by ``tests/test_simulate.py`` (exact paths) and ``experiments/knife_edge.py`` (exact paths
and the radio map).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig

SCREEN_HEIGHT_M = 12.0
USER_DISTANCE_M = 50.0
USER_HEIGHT_M = 1.5
RX_HEIGHT_M = 10.0
BEHIND_M = np.array([12.0, 44.0, 92.0, 156.0])
#: Isotropic antennas (P.526's assumption), the screen's edge needs no more than two interactions, no refraction.
EXACT_CONFIG = RayTraceConfig(antenna="iso", max_depth=2, refraction=False, samples_per_tx=1_000_000, seed=1)


def points(behind_m: np.ndarray = BEHIND_M) -> np.ndarray:
    """Receiver positions ``[len(behind_m), 3]`` on the line through the user, ``behind_m`` behind the screen."""
    behind_m = np.asarray(behind_m, float)
    return np.c_[behind_m, np.zeros(len(behind_m)), np.full(len(behind_m), RX_HEIGHT_M)]


def write_knife_edge_scene(folder: str | Path) -> RadioMapJob:
    """A perfectly conducting screen at x = 0 (800 m wide, from z = -500 m to the edge at 12 m, so that only its top
    edge diffracts) as a Mitsuba scene in ``folder``; the job of one user at (-50, 0, 1.5) and a 200 x 40 m plane
    of 4 m cells at 10 m behind the screen."""
    import trimesh

    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    corners = [[0, -400, -500], [0, 400, -500], [0, 400, SCREEN_HEIGHT_M], [0, -400, SCREEN_HEIGHT_M]]
    faces = [[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]]  # both sides
    trimesh.Trimesh(corners, faces, process=False).export(folder / "meshes" / "s.ply")
    (folder / "scene.xml").write_text(
        '<scene version="2.1.0"><bsdf type="radio-material" id="uav-screen"><float name="relative_permittivity" '
        'value="1.0"/><float name="conductivity" value="1e7"/><float name="thickness" value="0.01"/></bsdf>'
        '<shape type="ply" id="screen"><string name="filename" value="meshes/s.ply"/>'
        '<boolean name="face_normals" value="true"/><ref id="uav-screen" name="bsdf"/></shape></scene>'
    )
    return RadioMapJob(
        str(folder / "scene.xml"), ((-USER_DISTANCE_M, 0.0, USER_HEIGHT_M),), (100.0, 0.0, RX_HEIGHT_M), (200.0, 40.0), 4.0
    )


def p526_path_gain_db(behind_m: np.ndarray, frequency_hz: float) -> np.ndarray:
    """Free space minus ITU-R P.526's single knife-edge loss J(v) (eq. 31, v > -0.78), isotropic antennas,
    at ``behind_m`` metres behind the screen at the receivers' height."""
    d1, d2 = USER_DISTANCE_M, np.asarray(behind_m, float)
    lam = 3e8 / frequency_hz
    h = SCREEN_HEIGHT_M - (USER_HEIGHT_M + (RX_HEIGHT_M - USER_HEIGHT_M) * d1 / (d1 + d2))  # edge above the line of sight
    v = h * np.sqrt(2 / lam * (1 / d1 + 1 / d2))
    j_db = 6.9 + 20 * np.log10(np.sqrt((v - 0.1) ** 2 + 1) + v - 0.1)
    return 20 * np.log10(lam / (4 * np.pi * np.hypot(d1 + d2, RX_HEIGHT_M - USER_HEIGHT_M))) - j_db
