"""Solar gains of the test cell: sun position, facade irradiance, glazing optics.

* Sun position and the Perez sky-diffuse irradiance on the facade come from
  pvlib; the ground-reflected part is ``rho_g * GHI * (1 - cos tilt) / 2`` with
  ``GHI = DNI cos Z + DHI`` (the ground reflectance varies per instance).
* Each glass pane's angular solar properties follow from its normal-incidence
  transmittance and reflectance: the pair is inverted for the interface
  (Fresnel) reflectance, hence the refractive index, and the internal
  transmittance of the slab (absorption); the Fresnel equations then give the
  pane's transmittance and reflectance at any angle (s and p averaged), and
  the panes are combined with their inter-reflections. Hemispherical
  integration gives the diffuse properties.
* Beam sunlight entering the cell is traced onto the floor plane: the part of
  the sunlit patch that falls inside the floor lands on the floor, the rest
  on the walls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

#: Incidence-angle grid for the glazing tables (degrees).
ANGLES_DEG = np.linspace(0.0, 90.0, 91)


def sun_position(times: pd.DatetimeIndex, latitude: float, longitude: float,
                 elevation: float) -> tuple[np.ndarray, np.ndarray]:
    """Apparent zenith and azimuth (degrees) at ``times`` (timezone-aware)."""
    import pvlib

    position = pvlib.solarposition.get_solarposition(times, latitude, longitude,
                                                     altitude=elevation)
    return position["apparent_zenith"].to_numpy(), position["azimuth"].to_numpy()


def facade_irradiance(times: pd.DatetimeIndex, zenith: np.ndarray, azimuth: np.ndarray,
                      dni: np.ndarray, dhi: np.ndarray, tilt: float, surface_azimuth: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(beam incident, sky diffuse, cos of incidence) on a surface; W/m².

    ``dni`` and ``dhi`` may be ``(n_instances, n_times)``: the Perez model is
    evaluated element-wise.
    """
    import pvlib

    cos_incidence = np.cos(np.radians(pvlib.irradiance.aoi(tilt, surface_azimuth, zenith,
                                                           azimuth)))
    cos_incidence = np.where(zenith < 90.0, np.clip(cos_incidence, 0.0, 1.0), 0.0)
    dni_extra = np.asarray(pvlib.irradiance.get_extra_radiation(times))
    airmass = np.asarray(pvlib.atmosphere.get_relative_airmass(np.minimum(zenith, 89.9)))
    shape = np.broadcast_shapes(np.shape(dni), np.shape(dhi), zenith.shape)
    dni_b = np.broadcast_to(dni, shape)
    dhi_b = np.broadcast_to(dhi, shape)
    flat = lambda a: np.broadcast_to(a, shape).reshape(-1)  # noqa: E731
    with np.errstate(invalid="ignore", divide="ignore"):
        sky = pvlib.irradiance.perez(tilt, surface_azimuth, flat(dhi_b), flat(dni_b),
                                     flat(dni_extra), flat(zenith), flat(azimuth),
                                     flat(airmass))
    sky = np.nan_to_num(np.asarray(sky, dtype=float).reshape(shape), nan=0.0)
    sky = np.where(np.broadcast_to(zenith, shape) < 90.0, np.clip(sky, 0.0, None), 0.0)
    # Below the horizon the sky dome still gives the isotropic share of DHI.
    night = np.broadcast_to(zenith, shape) >= 90.0
    sky = np.where(night, dhi_b * (1 + np.cos(np.radians(tilt))) / 2, sky)
    beam = dni_b * cos_incidence
    return beam, sky, cos_incidence


# Glazing ---------------------------------------------------------------

def invert_pane(tau0: np.ndarray, rho0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interface reflectance ``r`` and internal transmittance ``t`` of a pane.

    Solves ``tau0 = (1-r)^2 t / (1 - r^2 t^2)`` and ``rho0 = r (1 + tau0 t)``
    (a slab with two identical interfaces and multiple reflections) by
    bisection on ``r`` in ``(0, rho0)``.
    """
    tau0 = np.asarray(tau0, dtype=float)
    rho0 = np.asarray(rho0, dtype=float)
    low = np.full(np.broadcast_shapes(tau0.shape, rho0.shape), 1e-6)
    high = np.broadcast_to(rho0, low.shape) * (1 - 1e-9)

    def residual(r):
        t = np.clip((rho0 - r) / (r * tau0), 0.0, 1.0)
        return (1 - r) ** 2 * t - tau0 * (1 - r * r * t * t)

    for _ in range(60):
        mid = 0.5 * (low + high)
        positive = residual(mid) > 0  # t too large -> r too small
        low = np.where(positive, mid, low)
        high = np.where(positive, high, mid)
    r = 0.5 * (low + high)
    t = np.clip((rho0 - r) / (r * tau0), 1e-9, 1.0)
    return r, t


def pane_angular(tau0: np.ndarray, rho0: np.ndarray, angles_deg: np.ndarray = ANGLES_DEG
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A pane's (transmittance, reflectance) at each angle: arrays ``(..., n_angles)``."""
    r0, t0 = invert_pane(tau0, rho0)
    root = np.sqrt(r0)
    n = ((1 + root) / (1 - root))[..., None]
    absorption = -np.log(t0)[..., None]           # K d at normal incidence
    theta = np.radians(np.minimum(angles_deg, 89.999))
    cos_i = np.cos(theta)
    cos_t = np.sqrt(1 - (np.sin(theta) / n) ** 2)
    t = np.exp(-absorption / cos_t)
    tau = np.zeros(np.broadcast_shapes(n.shape, theta.shape))
    rho = np.zeros_like(tau)
    for r in (((cos_i - n * cos_t) / (cos_i + n * cos_t)) ** 2,
              ((n * cos_i - cos_t) / (n * cos_i + cos_t)) ** 2):
        tau_x = (1 - r) ** 2 * t / (1 - r * r * t * t)
        tau += 0.5 * tau_x
        rho += 0.5 * r * (1 + tau_x * t)
    # Exactly at grazing incidence nothing is transmitted.
    tau[..., angles_deg >= 90.0] = 0.0
    rho[..., angles_deg >= 90.0] = 1.0
    return tau, rho


def hemispherical(values: np.ndarray, angles_deg: np.ndarray = ANGLES_DEG) -> np.ndarray:
    """Diffuse (hemispherical) average ``2 ∫ X(θ) cos θ sin θ dθ`` over the last axis."""
    theta = np.radians(angles_deg)
    weight = 2 * np.cos(theta) * np.sin(theta)
    return np.trapezoid(values * weight, theta, axis=-1)


@dataclass
class GlazingTables:
    """Double glazing solar properties, per instance and incidence angle.

    Front: sunlight from outside. ``absorbed_out``/``absorbed_in`` are the
    fractions absorbed in the outer/inner pane. ``back_*``: diffuse light from
    the room side (transmitted out, absorbed in outer/inner pane).
    """

    transmittance: np.ndarray     # (N, n_angles)
    absorbed_out: np.ndarray
    absorbed_in: np.ndarray
    diffuse_transmittance: np.ndarray  # (N,)
    diffuse_absorbed_out: np.ndarray
    diffuse_absorbed_in: np.ndarray
    back_transmittance: np.ndarray
    back_absorbed_out: np.ndarray
    back_absorbed_in: np.ndarray


def double_glazing(tau: np.ndarray, rho_front: np.ndarray, rho_back: np.ndarray,
                   dirt: np.ndarray) -> GlazingTables:
    """Two identical panes (outer one with the dirt correction on its transmittance).

    The dirt correction multiplies the outer pane's normal transmittance; the
    reflectances stay, so the removed light is absorbed in the pane.
    """
    tables = []
    for tau_pane in (tau * dirt, tau):
        rho_avg = 0.5 * (rho_front + rho_back)
        t, r = pane_angular(tau_pane, rho_avg)
        rf = r * (rho_front / rho_avg)[..., None]
        rb = r * (rho_back / rho_avg)[..., None]
        tables.append((t, rf, rb))
    (t1, r1f, r1b), (t2, r2f, r2b) = tables
    a1f, a1b = 1 - t1 - r1f, 1 - t1 - r1b
    a2f, a2b = 1 - t2 - r2f, 1 - t2 - r2b
    # At grazing incidence (r = 1, t = 0) the products below are 0 * inf: zero.
    with np.errstate(divide="ignore", invalid="ignore"):
        between = 1 / (1 - r1b * r2f)
        fix = lambda x: np.nan_to_num(x, nan=0.0, posinf=0.0)  # noqa: E731
        transmittance = fix(t1 * t2 * between)
        absorbed_out = fix(a1f + t1 * r2f * a1b * between)
        absorbed_in = fix(t1 * a2f * between)
        back_t = fix(t2 * t1 * between)
        back_in = fix(a2b + t2 * r1b * a2f * between)
        back_out = fix(t2 * a1b * between)
    return GlazingTables(
        transmittance=transmittance, absorbed_out=absorbed_out, absorbed_in=absorbed_in,
        diffuse_transmittance=hemispherical(transmittance),
        diffuse_absorbed_out=hemispherical(absorbed_out),
        diffuse_absorbed_in=hemispherical(absorbed_in),
        back_transmittance=hemispherical(back_t), back_absorbed_out=hemispherical(back_out),
        back_absorbed_in=hemispherical(back_in))


def angle_lookup(cos_incidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid index and weight of each incidence angle for :data:`ANGLES_DEG` tables."""
    angle = np.degrees(np.arccos(np.clip(cos_incidence, 0.0, 1.0)))
    step = ANGLES_DEG[1] - ANGLES_DEG[0]
    index = np.clip((angle // step).astype(int), 0, len(ANGLES_DEG) - 2)
    weight = (angle - ANGLES_DEG[index]) / step
    return index, weight


def lookup(table: np.ndarray, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``table`` (N, n_angles) at per-time angles -> (N, n_times)."""
    return table[:, index] * (1 - weight) + table[:, index + 1] * weight


# Beam sunlight inside the cell -----------------------------------------

def beam_floor_fraction(zenith: np.ndarray, azimuth: np.ndarray, window_x: tuple[float, float],
                        window_z: tuple[float, float], floor_x: tuple[float, float],
                        depth: float, samples: int = 24) -> np.ndarray:
    """Fraction of the beam entering a south window (plane y = 0) that lands on the floor.

    The sunlit patch is the window projected along the sun's rays onto the
    floor plane; what falls beyond the floor's extent (x outside ``floor_x``,
    or deeper than ``depth``) hits the walls instead.
    """
    zen = np.radians(np.minimum(zenith, 89.9))
    az = np.radians(azimuth)
    # Direction of travel of the rays (x east, y north, z up).
    dx, dy, dz = -np.sin(zen) * np.sin(az), -np.sin(zen) * np.cos(az), -np.cos(zen)
    fraction = np.zeros_like(zen)
    entering = (dy > 1e-6) & (zenith < 90.0)
    a = np.where(entering, dx / -dz, 0.0)
    b = np.where(entering, dy / -dz, 0.0)
    z = window_z[0] + (np.arange(samples) + 0.5) / samples * (window_z[1] - window_z[0])
    width = window_x[1] - window_x[0]
    for zk in z:
        y = b * zk
        x0 = window_x[0] + a * zk
        overlap = np.clip(np.minimum(x0 + width, floor_x[1]) - np.maximum(x0, floor_x[0]),
                          0.0, width) / width
        fraction += np.where(y <= depth, overlap, 0.0)
    return np.where(entering, fraction / samples, 1.0)
