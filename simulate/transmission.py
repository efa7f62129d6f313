"""The exact straight path from a user through the walls to a cell: what fills the cells no ray of the radio map hit.

Sionna's radio map estimates each cell's path gain from the rays that happen to cross it: far from
the user, behind walls, a 4 m cell gets few rays or none by chance. Its walls are thin slabs that
rays pass through (refraction without deflection), so every cell has one path that needs no
sampling at all: the straight line from the user, through each wall it crosses. This module
computes that path exactly, as Sionna's ``PathSolver`` does (checked against it in
``tests/test_simulate.py``):

- the wall crossings from Mitsuba ray intersections with the scene's meshes;
- at each crossing, ITU-R P.2040-4's single-layer slab transmission (eqs 37, 43b and 44) of the
  wall's material at its incidence angle, the vertical dipole's field split into the TE and TM
  parts of that crossing;
- free space over the path's length and the user's antenna gain towards the cell.

A path that crosses more walls than the tracer's ``max_depth`` interactions does not exist, as in
the reference. The result is deterministic: no lattice, no Monte Carlo gaps.
"""

from __future__ import annotations

import numpy as np

EPS0 = 8.854187817e-12
#: The key of ``direct_path_gains``' slabs for every shape not named.
EVERY_SHAPE = "*"


def complex_permittivity(eps_r: float, sigma_s_m: float, frequency_hz: float) -> complex:
    """eta = eps_r - j sigma / (omega eps0) (ITU-R P.2040 eq. 9b)."""
    return complex(eps_r, -sigma_s_m / (2 * np.pi * frequency_hz * EPS0))


def slab_transmission(cos_theta: np.ndarray, eta: complex, thickness_m: float, wavelength_m: float) -> tuple:
    """(|T_TE|^2, |T_TM|^2) of a single-layer slab in vacuum at incidence cosine ``cos_theta`` (P.2040-4 eqs 37, 43b, 44)."""
    cos_theta = np.asarray(cos_theta, float)
    root = np.sqrt(eta - (1.0 - cos_theta**2) + 0j)
    r_te = (cos_theta - root) / (cos_theta + root)  # eq. 37a
    r_tm = (eta * cos_theta - root) / (eta * cos_theta + root)  # eq. 37b
    q = 2 * np.pi * thickness_m / wavelength_m * root  # eq. 44
    one, two = np.exp(-1j * q), np.exp(-2j * q)
    t_te = (1 - r_te**2) * one / (1 - r_te**2 * two)  # eq. 43b
    t_tm = (1 - r_tm**2) * one / (1 - r_tm**2 * two)
    return np.abs(t_te) ** 2, np.abs(t_tm) ** 2


def antenna_gain(pattern: str, cos_zenith: np.ndarray) -> np.ndarray:
    """Power gain of a vertical antenna towards a direction of zenith cosine ``cos_zenith``: ``iso`` or ``hw_dipole``
    (a half-wave dipole, 1.643 (cos(pi/2 cos t) / sin t)^2, Balanis 4-84)."""
    cos_zenith = np.asarray(cos_zenith, float)
    if pattern == "iso":
        return np.ones_like(cos_zenith)
    if pattern == "hw_dipole":
        return 1.643 * np.cos(np.pi / 2 * cos_zenith) ** 2 / np.maximum(1.0 - cos_zenith**2, 1e-12)
    raise ValueError(f"no direct-path model for the antenna pattern {pattern!r} (iso or hw_dipole)")


def direct_path_gains(
    mi,  # noqa: ANN001 - the mitsuba module, as Sionna loaded it
    mi_scene,  # noqa: ANN001
    user: np.ndarray,
    cells: np.ndarray,
    slabs: dict[str, tuple[complex, float]],
    wavelength_m: float,
    *,
    pattern: str = "hw_dipole",
    max_crossings: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """(gain [C], walls crossed [C]) of the straight path from ``user`` [3] to each of ``cells`` [C, 3] through the
    scene's surfaces. ``slabs``: each shape's slab (complex permittivity, thickness [m]) by its id, ``EVERY_SHAPE`` for
    the shapes not named. Paths crossing more than ``max_crossings`` surfaces get 0 (their count reads
    ``max_crossings + 1``)."""
    user = np.asarray(user, float)
    cells = np.asarray(cells, float)
    ray_dir = cells - user
    length = np.linalg.norm(ray_dir, axis=1)
    k = ray_dir / np.maximum(length, 1e-9)[:, None]
    gain = (wavelength_m / (4 * np.pi * np.maximum(length, 1e-3))) ** 2 * antenna_gain(pattern, k[:, 2])
    # The vertical antenna's field is along theta-hat of the departure direction.
    sin_t = np.sqrt(np.maximum(1.0 - k[:, 2] ** 2, 1e-12))
    field = np.c_[k[:, 2] * k[:, 0] / sin_t, k[:, 2] * k[:, 1] / sin_t, -sin_t]
    # each wall's shape and slab; a crossing of a shape without one (the ground) carries nothing, so it is not looked up
    walls = [(shape, slabs.get(shape.id(), slabs.get(EVERY_SHAPE))) for shape in mi_scene.shapes()]
    shapes = [(mi.ShapePtr(shape), slab) for shape, slab in walls if slab is not None]
    origin = np.broadcast_to(user, cells.shape).copy()
    left = length.copy()
    crossed = np.zeros(len(cells), np.int64)
    todo = np.arange(len(cells))
    while len(todo):
        o, d = origin[todo], k[todo]
        ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, j]) for j in range(3))), mi.Vector3f(*(mi.Float(d[:, j]) for j in range(3))))
        ray.maxt = mi.Float(np.maximum(left[todo], 0.0))
        si = mi_scene.ray_intersect(ray)
        hit = np.asarray(si.is_valid(), bool)
        todo = todo[hit]
        t = np.asarray(si.t)[hit]
        normal = np.c_[np.asarray(si.n.x)[hit], np.asarray(si.n.y)[hit], np.asarray(si.n.z)[hit]]
        crossed[todo] += 1
        kk = k[todo]
        ground = (o[hit, 2] + kk[:, 2] * t) < 1e-3  # a path into the ground does not come out again
        crossed[todo[ground]] = max_crossings + 1
        te = np.cross(kk, normal)
        norm = np.linalg.norm(te, axis=1)
        # At normal incidence there is no plane of incidence: TE and TM coincide, any split will do.
        te = np.where(norm[:, None] > 1e-9, te / np.maximum(norm, 1e-12)[:, None], field[todo])
        share_te = np.clip((field[todo] * te).sum(axis=1) ** 2, 0.0, 1.0)
        cos_theta = np.abs((normal * kk).sum(axis=1))
        power = np.zeros(len(todo))
        for pointer, slab in shapes:  # each crossing through its own shape's slab
            on = np.asarray(si.shape == pointer, bool)[hit]
            if on.any():
                t_te, t_tm = slab_transmission(cos_theta[on], slab[0], slab[1], wavelength_m)
                power[on] = share_te[on] * t_te + (1 - share_te[on]) * t_tm
        gain[todo] *= power
        step = t + 1e-3  # past the surface, then on to the next one
        origin[todo] += kk * step[:, None]
        left[todo] -= step
        todo = todo[(crossed[todo] <= max_crossings) & (left[todo] > 0)]
    gain[crossed > max_crossings] = 0.0
    return gain, np.minimum(crossed, max_crossings + 1)
