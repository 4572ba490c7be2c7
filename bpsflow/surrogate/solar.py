"""Solar gains of the test cell: sun position, facade irradiance, glazing optics.

* The sun position is EnergyPlus's own (its daily Fourier series for the
  declination and the equation of time, the hour angle at the end of each
  time step), since the surrogate must reproduce EnergyPlus rather than the
  true sun: pvlib's SPA differs from it by up to 0.3 degrees. EnergyPlus
  computes the beam's angle of incidence on surfaces (and the sunlit patch
  inside) from the declination and equation of time *averaged* over each
  shading-calculation period (20 days by default): in July that sun stands
  up to a degree off the daily one, which moves the beam on a south facade
  by several per cent, so the surrogate does the same (:func:`sun_positions`).
* The Perez sky-diffuse irradiance on the facade comes from pvlib; the
  ground-reflected part is ``rho_g * GHI * (1 - cos tilt) / 2`` with
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

import functools
import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import pandas as pd

#: Incidence-angle grid for the glazing tables (degrees).
ANGLES_DEG = np.linspace(0.0, 90.0, 91)


#: EnergyPlus's Fourier coefficients (constant, then sin and cos of x, 2x, 3x,
#: 4x with x = 0.017167 x day of year) of the sine of the solar declination
#: and of the equation of time (hours); WeatherManager, CalculateDailySolarCoeffs.
_SINE_DECLINATION = (0.00561800, 0.0657911, -0.392779, 0.00064440, -0.00618495,
                     -0.00010101, -0.00007951, -0.00011691, 0.00002096)
_EQUATION_OF_TIME = (0.00021971, -0.122649, 0.00762856, -0.156308, -0.0530028,
                     -0.00388702, -0.00123978, -0.00270502, -0.00167992)
#: EnergyPlus's default shading-calculation update frequency (days).
SHADING_DAYS = 20


def daily_solar_coefficients(day_of_year: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sine of the solar declination and the equation of time (h) of each day, as EnergyPlus."""
    x = 0.017167 * np.asarray(day_of_year, dtype=float)
    terms = [np.ones_like(x)]
    for k in (1, 2, 3, 4):
        terms += [np.sin(k * x), np.cos(k * x)]
    return (sum(c * t for c, t in zip(_SINE_DECLINATION, terms)),
            sum(c * t for c, t in zip(_EQUATION_OF_TIME, terms)))


def _position(hours: np.ndarray, sine_declination: np.ndarray, equation_of_time: np.ndarray,
              latitude: float, longitude: float, time_zone: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Zenith and azimuth (degrees, azimuth clockwise from north) at local standard ``hours``."""
    hour_angle = np.radians(15.0 * (12.0 - (hours + longitude / 15.0 - time_zone
                                            + equation_of_time)))
    cos_declination = np.sqrt(1.0 - sine_declination ** 2)
    phi = np.radians(latitude)
    up = np.sin(phi) * sine_declination + np.cos(phi) * cos_declination * np.cos(hour_angle)
    east = cos_declination * np.sin(hour_angle)
    north = np.cos(phi) * sine_declination - np.sin(phi) * cos_declination * np.cos(hour_angle)
    zenith = np.degrees(np.arccos(np.clip(up, -1.0, 1.0)))
    return zenith, np.degrees(np.arctan2(east, north)) % 360.0


class _ContentMemo:
    """Results of the sun-geometry functions below, by the content of their arguments; the
    least recently used go once they hold more than ``limit_bytes``."""

    def __init__(self, limit_bytes: int):
        self.entries: OrderedDict[bytes, tuple] = OrderedDict()   # key -> (result, bytes)
        self.held = 0
        self.limit_bytes = limit_bytes
        self.lock = threading.Lock()   # a Dask worker's threads share the module

    @staticmethod
    def key(name: str, args: tuple) -> bytes:
        digest = hashlib.blake2b(name.encode(), digest_size=20)
        for value in args:
            if isinstance(value, pd.DatetimeIndex):
                value = value.asi8
            if isinstance(value, np.ndarray):
                array = np.ascontiguousarray(value)
                digest.update(f"{array.dtype.str}{array.shape}".encode() + array.tobytes())
            else:   # scalars, None, tuples of floats: repr is exact
                digest.update(repr(value).encode())
            digest.update(b"|")
        return digest.digest()

    def get(self, key: bytes):
        with self.lock:
            if key not in self.entries:
                return None
            self.entries.move_to_end(key)
            return self.entries[key][0]

    def put(self, key: bytes, result, size: int) -> None:
        with self.lock:
            if key not in self.entries:
                self.entries[key] = (result, size)
                self.held += size
            while self.held > self.limit_bytes and len(self.entries) > 1:
                self.held -= self.entries.popitem(last=False)[1][1]


_SOLAR_MEMO = _ContentMemo(128 << 20)


def _memoised(function):
    """Memoise a pure function of arrays by their content (returned arrays read-only).

    A diagnosis or a sample simulates the same weather days many times with
    different inputs; the sun's geometry on each face and the Perez sky are
    the same every time. Read-only results make a caller that would modify
    one fail instead of changing the next call's answer.
    """
    @functools.wraps(function)
    def memoised(*args, **kwargs):
        named = tuple(item for name in sorted(kwargs) for item in (name, kwargs[name]))
        key = _SOLAR_MEMO.key(function.__name__, args + named)
        cached = _SOLAR_MEMO.get(key)
        if cached is not None:
            return cached
        result = function(*args, **kwargs)
        arrays = [a for a in (result if isinstance(result, tuple) else (result,))
                  if isinstance(a, np.ndarray)]
        for array in arrays:
            array.flags.writeable = False
        _SOLAR_MEMO.put(key, result, sum(a.nbytes for a in arrays))
        return result
    return memoised


@_memoised
def sun_positions(step_ends: pd.DatetimeIndex, latitude: float, longitude: float,
                  time_zone: float, shading_days: int | None = SHADING_DAYS
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EnergyPlus's sun at the end of each time step of a run period.

    Parameters
    ----------
    step_ends : DatetimeIndex
        Naive local-standard-time ends of the steps, from the run period's
        first day on.
    latitude, longitude : float
        Site (degrees north, degrees east).
    time_zone : float
        Hours from UTC.
    shading_days : int or None
        Shading-calculation update frequency (days; ``None``: every time step).

    Returns
    -------
    zenith, azimuth
        The sun of each step (degrees): sun up/down, site quantities, sky
        diffuse.
    beam_zenith, beam_azimuth
        The sun EnergyPlus takes for the beam's incidence on surfaces: the
        declination and equation of time averaged over each shading period
        (``shading_days`` from the run period's first day, the last one cut
        at the period's end).
    """
    # EnergyPlus's hour 24 (the step ending at midnight) belongs to the day before.
    starts = step_ends - pd.Timedelta(seconds=1)
    day = np.asarray(starts.day_of_year, dtype=int)
    hours = np.asarray((step_ends - starts.normalize()) / pd.Timedelta(hours=1), dtype=float)
    sine, equation = daily_solar_coefficients(day)
    zenith, azimuth = _position(hours, sine, equation, latitude, longitude, time_zone)
    if shading_days is None:
        return zenith, azimuth, zenith, azimuth
    # Day index within the period (the period may cross a year's end).
    day_index = np.concatenate([[0], np.cumsum(np.diff(day) != 0)])
    window = day_index // shading_days
    beam_sine, beam_equation = np.empty_like(sine), np.empty_like(equation)
    for w in np.unique(window):
        steps = window == w
        days = np.unique(day[steps])
        mean_sine, mean_equation = daily_solar_coefficients(days)
        beam_sine[steps], beam_equation[steps] = mean_sine.mean(), mean_equation.mean()
    beam_zenith, beam_azimuth = _position(hours, beam_sine, beam_equation, latitude, longitude,
                                          time_zone)
    return zenith, azimuth, beam_zenith, beam_azimuth


#: Extraterrestrial irradiance (W/m²) in EnergyPlus's Perez sky brightness.
PEREZ_EXTRATERRESTRIAL = 1353.0


def energyplus_airmass(zenith: np.ndarray) -> np.ndarray:
    """Relative air mass as EnergyPlus's Perez model takes it (sea level)."""
    zenith = np.minimum(np.asarray(zenith, dtype=float), 89.9)
    cos_zenith = np.cos(np.radians(zenith))
    with np.errstate(invalid="ignore"):
        kasten = 1.0 / (cos_zenith + 0.15 * (93.9 - zenith) ** -1.253)
    return np.where(zenith <= 75.0, 1.0 / cos_zenith, kasten)


@_memoised
def facade_irradiance(times: pd.DatetimeIndex, zenith: np.ndarray, azimuth: np.ndarray,
                      dni: np.ndarray, dhi: np.ndarray, tilt: float, surface_azimuth: float,
                      beam_zenith: np.ndarray | None = None,
                      beam_azimuth: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(beam incident, sky diffuse, cos of incidence) on a surface; W/m².

    ``dni`` and ``dhi`` may be ``(n_instances, n_times)``: the Perez model is
    evaluated element-wise. The beam's incidence uses ``beam_zenith`` and
    ``beam_azimuth`` when given (EnergyPlus's shading-period sun), else the
    sun of the step.
    """
    import pvlib

    beam_zenith = zenith if beam_zenith is None else beam_zenith
    beam_azimuth = azimuth if beam_azimuth is None else beam_azimuth
    cos_incidence = np.cos(np.radians(pvlib.irradiance.aoi(tilt, surface_azimuth, beam_zenith,
                                                           beam_azimuth)))
    cos_incidence = np.where((zenith < 90.0) & (beam_zenith < 90.0),
                             np.clip(cos_incidence, 0.0, 1.0), 0.0)
    # EnergyPlus's Perez inputs: a constant 1353 W/m² extraterrestrial
    # irradiance and its air mass (1/cos Z, Kasten's form beyond 75 degrees).
    dni_extra = np.full(zenith.shape, PEREZ_EXTRATERRESTRIAL)
    airmass = energyplus_airmass(zenith)
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

@_memoised
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
