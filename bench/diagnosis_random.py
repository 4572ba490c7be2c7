"""Randomised diagnosis benchmark: hidden effects drawn at random, scored blind (issue 14).

``bench/diagnosis_bench.py --random N --seed S`` draws ``N`` truths
(:func:`draw_truths`) and, for each, synthesises measurements of the shipped
model plus a hidden effect written here as plain EnergyPlus objects
(:func:`hidden_objects`), runs :func:`bpsflow.diagnosis.workflow.diagnose`
with the user's config only (the effect is never named to it), and scores the
answer (:func:`score`). ``--nulls K`` adds ``K`` null datasets diagnosed in
batches that share the base fit (:func:`run_nulls`).

The space of truths
-------------------
* **family**: ``gain``, ``aperture``, ``infiltration``, ``mass``, ``two`` (two
  effects of different families at once) or ``null`` (no effect);
* **shape**: a gain's day set (weekdays, weekends, all days, one weekday),
  start and end hour and radiant fraction 0–0.7; an aperture's plane (any
  wall orientation of the diagnosed zone, or the roof), written as an
  ``OtherEquipment`` whose hourly schedule is the irradiance on that plane
  computed here (:func:`plane_irradiance`, isotropic sky, independent of
  :mod:`bpsflow.diagnosis.extensions`); an infiltration law's terms (any
  non-empty subset of A, B·|ΔT|, C·V, D·V² of ``ZoneInfiltration:DesignFlowRate``);
  a thermal mass (an ``InternalMass`` of a heavy concrete construction, 0.1–0.3 m,
  of a given area);
* **size**: 1× to 10× the family's detection limit (log-uniform), see
  :func:`detection_limit`;
* **season**: test start in November, January, February or March (38 days on
  the test cell, 24 on the office; a start in December would leave the
  weather year);
* **setpoint regime**: constant, or a night setback (by overriding the test's
  ``setpoint_c``/``setback_c``/``setback_*_hour``, as the user's own config
  would say); a thermal-mass truth always has a setback, because under a
  constant setpoint with ideal control the mass barely exchanges heat with
  the air and no size would be detectable;
* **sensor noise**: AR(1) relative noise, 1 % standard deviation (the shipped
  sensor), lag-1 autocorrelation φ drawn in 0–0.9;
* **model and backend**: the test cell (``configs/diagnosis.yaml``) on either
  backend; the 3-zone office (``configs/office3zone_diagnosis.yaml``) on
  EnergyPlus only (the surrogate is one-zone).

Detection limits
----------------
One measured figure anchors them all: the smallest wind-infiltration
coefficient found in ≥ 9 of 10 noisy datasets by the detection sweep of
``bench/diagnosis_bench.py`` (``diagnose_wind_detection_limit`` in
``bench/results.json``: 0.0004 m³/s per m/s, 1 % AR(1) noise, the shipped
period). On each backend the bench measures that leak's effect on the shipped
scenario (:func:`anchor_ratio`: hourly std of the change in the diagnosed
output over its mean; the noise is relative, so this ratio is what a
detection depends on). An effect is at 1× its family's detection limit when
its own change of the output, in its own truth's period, setpoint regime
and model, has that same ratio. The sizes are found in two steps: the bench's
own simple physics gives a first guess (:func:`build_truth`: equal hourly std
of the added heat flow, no dynamics), then the effect runs alone on the
backend and is rescaled to the drawn multiple (:func:`synthesise`). So the
limits are a physical scaling of one measured sweep, measured on the backend
per truth; not a sweep per family.

Equal std is not equal detectability: the diagnosis first refits the existing
inputs, and an effect they can mimic (a south aperture and the south window's
dirt factor) leaves less in the residuals. Each row also records, per effect,
its *unabsorbed multiple*: the drawn multiple times the share of the effect
that no refit of the existing inputs reproduces, over the anchor's own such
share (:func:`unabsorbed_shares`, from one sensitivity run per fitted input).
The accuracy is reported by that multiple too, as an analysis; the drawn sizes
and the goal are not changed by it.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import time
import traceback
from dataclasses import asdict, dataclass, field
from datetime import date, timedelta
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]

#: The shipped models a truth may use: (diagnosis config, its truth-values file, test days).
MODELS = {
    "test_cell": (ROOT / "configs" / "diagnosis.yaml",
                  ROOT / "configs" / "diagnosis_truth_values.yaml", 38),
    "office3zone": (ROOT / "configs" / "office3zone_diagnosis.yaml",
                    ROOT / "configs" / "office3zone_diagnosis_truth_values.yaml", 24),
}
#: Models the one-zone surrogate can run.
SURROGATE_MODELS = ("test_cell",)

FAMILIES = ("gain", "aperture", "infiltration", "mass", "airing", "two", "null")
EFFECT_FAMILIES = ("gain", "aperture", "infiltration", "mass", "airing")
#: Extensions a correct diagnosis may accept for each family.
FAMILY_EXTENSIONS = {
    "gain": ("internal_gain_schedule",),
    "aperture": ("solar_aperture",),
    "infiltration": ("infiltration", "infiltration_wind", "envelope_ua"),
    "mass": ("thermal_mass",),
    "airing": ("scheduled_air_exchange",),
}
#: Day sets of a drawn gain -> the ``Schedule:Compact`` ``For:`` day type.
DAY_SETS = {"weekdays": "Weekdays", "weekends": "Weekends", "all days": "AllDays",
            "monday": "Monday", "tuesday": "Tuesday", "wednesday": "Wednesday",
            "thursday": "Thursday", "friday": "Friday", "saturday": "Saturday",
            "sunday": "Sunday"}
INFILTRATION_TERMS = ("A", "B", "C", "D")
#: Fitted-parameter names that measure each infiltration term (today's and the planned ones).
TERM_KEYS = {
    "A": ("infiltration_a_m3s", "extra_conductance_m3s"),
    "B": ("infiltration_b_m3s_per_k",),
    "C": ("infiltration_c_m3s_per_ms", "infiltration_wind_m3s_per_ms"),
    "D": ("infiltration_d_m3s_per_m2s2",),
}
#: The key of a drawn effect's true size in :attr:`Built.sizes` (and its limit's).
SIZE_UNITS = {"gain": "W", "airing": "m3s", "aperture": "m2", "mass": "m2"}
SIZE_KEYS = {"gain": ("scheduled_gain_w",), "aperture": ("solar_aperture_m2",),
             "airing": ("scheduled_air_flow_m3s",),
             "mass": ("internal_mass_area_m2",)}
START_MONTHS = (11, 1, 2, 3)

#: The measured anchor of every detection limit (m³/s per m/s), and the scenario it was
#: measured on: bench/diagnosis_bench.py's sweep on configs/diagnosis.yaml as shipped.
WIND_LIMIT_M3S_PER_MS = 0.0004
WIND_LIMIT_SCENARIO = {"start": (11, 1), "days": 38, "warmup": 3, "setpoint_c": 30.0}
#: Air's volumetric heat capacity (J/m³K), as in the surrogate's outdoor-density basis.
RHO_CP = 1.2 * 1005.0
#: Heavy mass: concrete (W/mK, kg/m³, J/kgK) and a still-air inside film (W/m²K).
CONCRETE = (1.95, 2240.0, 900.0)
MASS_FILM_W_M2K = 3.0
#: Ground reflectance of the bench's own plane irradiance.
GROUND_REFLECTANCE = 0.2
#: Sensor noise: relative AR(1), bound = 3 standard deviations (the shipped sensor's 1 %).
NOISE_BOUND = 0.03


@dataclass
class Effect:
    """One hidden effect: its family, shape and size in detection limits."""

    family: str
    multiple: float
    shape: dict = field(default_factory=dict)


@dataclass
class Truth:
    """One drawn truth: model, backend, period, setpoint regime, noise and effects."""

    index: int
    family: str
    model: str
    backend: str
    start: tuple[int, int]
    setpoint_c: float
    setback: tuple[float, int, int] | None
    phi: float
    noise_seed: int
    effects: list[Effect] = field(default_factory=list)

    @property
    def label(self) -> str:
        return f"r{self.index:03d}_{self.family}"

    def describe(self) -> str:
        regime = ("constant" if self.setback is None else
                  f"setback {self.setback[0]:g} °C {self.setback[1]}-{self.setback[2]} h")
        return (f"{self.model}/{self.backend}, from {self.start[0]:02d}-{self.start[1]:02d}, "
                f"{self.setpoint_c:g} °C {regime}, noise φ {self.phi:.2f}")


# --------------------------------------------------------------------------- drawing


def _draw_effect(rng: np.random.Generator, family: str) -> Effect:
    multiple = float(math.exp(rng.uniform(0.0, math.log(10.0))))
    if family == "gain":
        start = int(rng.integers(0, 21))
        end = int(min(24, start + rng.integers(2, 13)))
        shape = {"days": str(rng.choice(list(DAY_SETS))), "start_hour": start,
                 "end_hour": end, "radiant_fraction": round(float(rng.uniform(0.0, 0.7)), 2)}
    elif family == "airing":
        # windows opened (or a door held open) for one to four hours on a day set
        start = int(rng.integers(0, 22))
        end = int(min(24, start + rng.integers(1, 5)))
        shape = {"days": str(rng.choice(list(DAY_SETS))), "start_hour": start, "end_hour": end}
    elif family == "aperture":
        shape = {"plane_draw": float(rng.uniform()),
                 "radiant_fraction": round(float(rng.uniform(0.0, 0.7)), 2)}
    elif family == "infiltration":
        while True:
            terms = [t for t in INFILTRATION_TERMS if rng.uniform() < 0.45]
            if terms:
                break
        shape = {"terms": terms}
    elif family == "mass":
        shape = {"thickness_m": round(float(rng.uniform(0.1, 0.3)), 3)}
    else:
        raise ValueError(family)
    return Effect(family, round(multiple, 3), shape)


def draw_truths(n: int, seed: int, backends: tuple[str, ...] = ("surrogate",),
                families: tuple[str, ...] = FAMILIES) -> list[Truth]:
    """``n`` truths drawn from the generator with ``seed`` (the same seed, the same truths).

    Parameters
    ----------
    n : int
        Number of truths.
    seed : int
        Seed of the generator (print it: a benchmark's seed is chosen at run time).
    backends : tuple of str
        Backends drawn from, uniformly; the office model only with ``energyplus``.
    families : tuple of str
        Families drawn from, uniformly (default :data:`FAMILIES`).
    """
    rng = np.random.default_rng(seed)
    truths = []
    for index in range(n):
        family = str(rng.choice(list(families)))
        backend = str(rng.choice(list(backends)))
        models = [m for m in MODELS if backend == "energyplus" or m in SURROGATE_MODELS]
        model = str(rng.choice(models))
        # days 1-20 of Nov-Mar: a 38-day test from 20 November still ends in the weather year
        month = int(rng.choice(START_MONTHS))
        day = int(rng.integers(1, 21))
        office = model == "office3zone"
        setpoint = round(float(rng.uniform(19.0, 22.0) if office else rng.uniform(24.0, 30.0)),
                         1)
        setback = None
        if family == "mass" or rng.uniform() < 0.4:
            setback = (round(setpoint - float(rng.uniform(3.0, 8.0)), 1),
                       int(rng.integers(17, 23)), int(rng.integers(5, 9)))
        effects: list[Effect] = []
        if family == "two":
            pair = rng.choice(list(EFFECT_FAMILIES), size=2, replace=False)
            effects = [_draw_effect(rng, str(f)) for f in pair]
            if "mass" in pair and setback is None:
                setback = (round(setpoint - 5.0, 1), 18, 7)
        elif family != "null":
            effects = [_draw_effect(rng, family)]
        phi = round(float(rng.uniform(0.0, 0.9)), 2)
        truths.append(Truth(index, family, model, backend, (month, day), setpoint, setback,
                            phi, int(rng.integers(0, 2**31 - 1)), effects))
    return truths


# --------------------------------------------------------------------------- the weather


@dataclass
class Weather:
    """The weather file's hourly columns and site, as the bench's own physics reads them."""

    dry_bulb: np.ndarray
    wind: np.ndarray
    ghi: np.ndarray
    dni: np.ndarray
    dhi: np.ndarray
    latitude: float
    longitude: float
    time_zone: float


def read_weather(config) -> Weather:
    from bpsflow.weather import read_epw

    epw = read_epw(config.model.weather)
    location = epw.header[0].split(",")
    c = epw.columns
    return Weather(c["dry_bulb_temperature"], c["wind_speed"], c["global_horizontal_radiation"],
                   c["direct_normal_radiation"], c["diffuse_horizontal_radiation"],
                   float(location[6]), float(location[7]), float(location[8]))


def plane_irradiance(weather: Weather, azimuth_deg: float, tilt_deg: float) -> np.ndarray:
    """Hourly irradiance (W/m²) on a plane, one value per weather-file row.

    The bench's own geometry, independent of the tool's: Spencer's (1971)
    declination and equation of time, the sun at the middle of each hour of
    local standard time, beam on the plane plus isotropic sky diffuse and
    ground-reflected irradiance (reflectance :data:`GROUND_REFLECTANCE`).

    Parameters
    ----------
    azimuth_deg : float
        The plane's outward normal, degrees clockwise from north.
    tilt_deg : float
        The plane's tilt from horizontal (0 = roof, 90 = wall).
    """
    rows = np.arange(len(weather.ghi))
    day = (rows // 24) % 365 + 1
    gamma = 2.0 * np.pi * (day - 1) / 365.0
    declination = (0.006918 - 0.399912 * np.cos(gamma) + 0.070257 * np.sin(gamma)
                   - 0.006758 * np.cos(2 * gamma) + 0.000907 * np.sin(2 * gamma)
                   - 0.002697 * np.cos(3 * gamma) + 0.00148 * np.sin(3 * gamma))
    equation_min = 229.18 * (0.000075 + 0.001868 * np.cos(gamma) - 0.032077 * np.sin(gamma)
                             - 0.014615 * np.cos(2 * gamma) - 0.040849 * np.sin(2 * gamma))
    solar_hour = (rows % 24 + 0.5 + (4.0 * (weather.longitude - 15.0 * weather.time_zone)
                                      + equation_min) / 60.0)
    omega = np.radians(15.0 * (solar_hour - 12.0))
    lat = math.radians(weather.latitude)
    east = -np.cos(declination) * np.sin(omega)
    north = np.sin(declination) * math.cos(lat) - np.cos(declination) * np.cos(omega) * math.sin(lat)
    up = np.sin(declination) * math.sin(lat) + np.cos(declination) * np.cos(omega) * math.cos(lat)
    az, tilt = math.radians(azimuth_deg), math.radians(tilt_deg)
    cos_incidence = (east * math.sin(tilt) * math.sin(az) + north * math.sin(tilt) * math.cos(az)
                     + up * math.cos(tilt))
    beam = np.where(up > 0.0, weather.dni * np.maximum(cos_incidence, 0.0), 0.0)
    return (beam + weather.dhi * (1.0 + math.cos(tilt)) / 2.0
            + weather.ghi * GROUND_REFLECTANCE * (1.0 - math.cos(tilt)) / 2.0)


def zone_planes(model, zone: str) -> list[tuple[str, float, float]]:
    """The zone's wall orientations and its roof: ``[(label, azimuth °, tilt °), ...]``.

    Read from the zone's ``BuildingSurface:Detailed`` vertices (outward normal
    by Newell's method, counter-clockwise vertices seen from outside), turned
    by the building's and the zone's north axes. Every wall orientation counts,
    whatever its boundary: an aperture there is the effect drawn, not a window
    of the model.
    """
    building = model.of_type("BUILDING")
    north = building[0].number("North Axis", 0.0) if building else 0.0
    zone_objects = [o for o in model.of_type("ZONE") if o.name.upper() == zone.upper()]
    if zone_objects and len(zone_objects[0].fields) > 1 and zone_objects[0].fields[1].strip():
        north += float(zone_objects[0].fields[1])    # the IDD's Direction of Relative North
    planes: dict[int, tuple[str, float, float]] = {}
    for surface in model.of_type("BUILDINGSURFACE:DETAILED"):
        if surface.get("Zone Name").upper() != zone.upper():
            continue
        if surface.get("Surface Type").upper() != "WALL":
            continue
        v = np.array(surface.vertices())
        normal = np.zeros(3)
        for a, b in zip(v, np.roll(v, -1, axis=0)):
            normal += [(a[1] - b[1]) * (a[2] + b[2]), (a[2] - b[2]) * (a[0] + b[0]),
                       (a[0] - b[0]) * (a[1] + b[1])]
        azimuth = (math.degrees(math.atan2(normal[0], normal[1])) + north) % 360.0
        key = int(round(azimuth)) % 360
        planes.setdefault(key, (f"wall {key}°", float(key), 90.0))
    return [planes[k] for k in sorted(planes)] + [("roof", 0.0, 0.0)]


# --------------------------------------------------------------------------- sizes


def evaluated_rows(year: int, start: tuple[int, int], days: int, warmup: int) -> np.ndarray:
    """Weather-file rows of a test's evaluated hours (after its warm-up days)."""
    from bpsflow.yearhours import day_rows

    first = date(year, *start) + timedelta(days=warmup)
    return (day_rows(first, days - warmup)[:, None] + np.arange(24)[None, :]).ravel()


def setpoint_profile(truth_setpoint: float, setback: tuple[float, int, int] | None,
                     n_days: int) -> np.ndarray:
    """Hourly heating setpoint (°C) over ``n_days`` whole days."""
    hours = np.arange(24)
    day = np.full(24, truth_setpoint)
    if setback is not None:
        back, start, end = setback
        day = np.where((hours >= start) | (hours < end), back, truth_setpoint)
    return np.tile(day, n_days)


def _gain_schedule_values(shape: dict, year: int, rows_days: list[date]) -> np.ndarray:
    out = []
    for d in rows_days:
        weekday = d.weekday()
        days = shape["days"]
        on_day = (days == "all days" or (days == "weekdays" and weekday < 5)
                  or (days == "weekends" and weekday >= 5)
                  or days == list(DAY_SETS)[3 + weekday])
        hours = np.arange(24)
        out.append(on_day * ((hours >= shape["start_hour"]) & (hours < shape["end_hour"])))
    return np.concatenate(out).astype(float)


def _mass_flow_per_m2(thickness: float, setpoint: np.ndarray) -> np.ndarray:
    """Heat flow (W/m²) from air to a lumped concrete slab following the setpoint profile."""
    k, rho, cp = CONCRETE
    # only the layer a day's swing reaches stores heat: the daily penetration depth
    depth = min(thickness, math.sqrt(k / (rho * cp) * 86400.0 / math.pi))
    capacity = rho * cp * depth
    surface = float(setpoint[0])
    flows = np.empty_like(setpoint)
    for i, air in enumerate(setpoint):
        flows[i] = MASS_FILM_W_M2K * (air - surface)
        surface += flows[i] * 3600.0 / capacity
    # two passes: start from the periodic state, not a cold slab
    for i, air in enumerate(setpoint):
        flows[i] = MASS_FILM_W_M2K * (air - surface)
        surface += flows[i] * 3600.0 / capacity
    return flows


def _term_drivers(weather: Weather, rows: np.ndarray, setpoint: np.ndarray) -> dict[str, np.ndarray]:
    delta = np.abs(setpoint - weather.dry_bulb[rows])
    v = weather.wind[rows]
    return {"A": np.ones_like(v), "B": delta, "C": v, "D": v * v}


def reference_std(weather: Weather, year: int) -> float:
    """Hourly std (W) of the wind leak at its measured detection limit, shipped scenario."""
    s = WIND_LIMIT_SCENARIO
    rows = evaluated_rows(year, s["start"], s["days"], s["warmup"])
    flow = WIND_LIMIT_M3S_PER_MS * weather.wind[rows]
    return float(np.std(RHO_CP * flow * (s["setpoint_c"] - weather.dry_bulb[rows])))


@dataclass
class Built:
    """A truth made concrete: its zone, the hidden objects and every effect's true size."""

    zone: str
    text: str
    files: dict[str, np.ndarray]
    sizes: list[dict]
    limits: list[dict]
    parts: list[str] = field(default_factory=list)     # each effect's objects alone


def build_truth(truth: Truth, scales: list[float] | None = None,
                taken: set[str] | None = None) -> Built:
    """Zone, hidden IDF text, schedule files and true sizes of ``truth`` (no simulation).

    Every size is the truth's multiple of the family's detection limit in this
    truth's period and setpoint regime: by the bench's own physics (module
    docstring), times ``scales[i]`` for effect ``i`` (the correction that
    :func:`synthesise` measures on the backend).
    """
    from bpsflow.config import load_config
    from bpsflow.diagnosis.extensions import diagnosis_zone, model_names
    from bpsflow.simulation.idf import model_objects

    config_path, _, days = MODELS[truth.model]
    config = load_config(config_path)
    model = model_objects(config.model)
    taken = set(taken or model_names(model))
    weather = read_weather(config)
    year = config.model.year
    warmup = config.model.tests[0].warmup_days
    rows = evaluated_rows(year, truth.start, days, warmup)
    first = date(year, *truth.start) + timedelta(days=warmup)
    row_days = [first + timedelta(days=d) for d in range(days - warmup)]
    setpoint = setpoint_profile(truth.setpoint_c, truth.setback, days - warmup)
    reference = reference_std(weather, year)
    text, files, sizes, limits = [], {}, [], []
    zone = diagnosis_zone(config, config.diagnosis.output if config.diagnosis else None,
                          None, model)
    for number, effect in enumerate(truth.effects):
        ref = reference * (scales[number] if scales else 1.0)
        name = _free(f"bpsflow_bench_{effect.family}_{number}", taken)
        if effect.family == "gain":
            unit = _gain_schedule_values(effect.shape, year, row_days)
            limit = ref / max(float(np.std(unit)), 1e-9)
            size = effect.multiple * limit
            text.append(_gain_text(name, _free(name + "_on", taken), zone, size, effect.shape))
            sizes.append({"family": "gain", "W": size, **effect.shape})
            limits.append({"family": "gain", "W": limit})
        elif effect.family == "aperture":
            planes = zone_planes(model, zone)
            label, azimuth, tilt = planes[int(effect.shape["plane_draw"] * len(planes))]
            irradiance = plane_irradiance(weather, azimuth, tilt)
            limit = ref / max(float(np.std(irradiance[rows])), 1e-9)
            size = effect.multiple * limit
            csv = f"{name}_irradiance.csv"
            files[csv] = irradiance
            text.append(_aperture_text(name, _free(name + "_sun", taken), zone, size,
                                       effect.shape["radiant_fraction"], csv, label))
            sizes.append({"family": "aperture", "m2": size, "plane": label,
                          "azimuth": azimuth, "tilt": tilt,
                          "radiant_fraction": effect.shape["radiant_fraction"]})
            limits.append({"family": "aperture", "m2": limit})
        elif effect.family == "infiltration":
            drivers = _term_drivers(weather, rows, setpoint)
            delta = setpoint - weather.dry_bulb[rows]
            terms = effect.shape["terms"]
            weights = {t: 1.0 / max(float(np.std(RHO_CP * drivers[t] * delta)), 1e-9)
                       for t in terms}
            unit_flow = sum(weights[t] * drivers[t] for t in terms)
            scale = ref / float(np.std(RHO_CP * unit_flow * delta))
            coefficients = {t: (weights[t] * scale * effect.multiple if t in terms else 0.0)
                            for t in INFILTRATION_TERMS}
            text.append(_infiltration_text(name, _free(name + "_always", taken), zone,
                                           coefficients))
            mean_drivers = {t: float(np.mean(d)) for t, d in drivers.items()}
            sizes.append({"family": "infiltration", "coefficients": coefficients,
                          "mean_drivers": mean_drivers,
                          "mean_flow_m3s": sum(coefficients[t] * mean_drivers[t]
                                               for t in INFILTRATION_TERMS)})
            limits.append({"family": "infiltration",
                           "coefficients": {t: weights[t] * scale for t in terms}})
        elif effect.family == "airing":
            # the loss of 1 m3/s of outdoor air while the schedule is on
            unit = RHO_CP * _gain_schedule_values(effect.shape, year, row_days) * (
                setpoint - weather.dry_bulb[rows])
            limit = ref / max(float(np.std(unit)), 1e-9)
            size = effect.multiple * limit
            text.append(_airing_text(name, _free(name + "_open", taken), zone, size,
                                     effect.shape))
            sizes.append({"family": "airing", "m3s": size, **effect.shape})
            limits.append({"family": "airing", "m3s": limit})
        elif effect.family == "mass":
            flows = _mass_flow_per_m2(effect.shape["thickness_m"], setpoint)
            limit = ref / max(float(np.std(flows)), 1e-9)
            size = effect.multiple * limit
            text.append(_mass_text(name, _free(name + "_concrete", taken),
                                   _free(name + "_layers", taken), zone, size,
                                   effect.shape["thickness_m"]))
            sizes.append({"family": "mass", "m2": size, **effect.shape})
            limits.append({"family": "mass", "m2": limit})
    return Built(zone, "\n".join(text), files, sizes, limits, text)


def _free(base: str, taken: set[str]) -> str:
    from bpsflow.diagnosis.extensions import free_name

    return free_name(base, taken)


# --------------------------------------------------------------------------- hidden objects
# Written for the bench, field by field: not the candidate extensions' snippets.


def _compact_rules(shape: dict) -> str:
    """``Schedule:Compact`` rules: 1 on the shape's days and hours, else 0."""
    start, end = shape["start_hour"], shape["end_hour"]
    day_rule = [f"Until: {start:02d}:00, 0"] if start > 0 else []
    day_rule.append(f"Until: {end:02d}:00, 1")
    if end < 24:
        day_rule.append("Until: 24:00, 0")
    rules = [f"For: {DAY_SETS[shape['days']]}", *day_rule]
    if shape["days"] != "all days":
        rules += ["For: AllOtherDays", "Until: 24:00, 0"]
    return ",\n  ".join(rules)


def _gain_text(name: str, schedule: str, zone: str, watts: float, shape: dict) -> str:
    return (f"! bench truth: {watts:.6g} W on {shape['days']}, {shape['start_hour']}-"
            f"{shape['end_hour']} h, radiant {shape['radiant_fraction']:g}\n"
            f"OtherEquipment, {name}, None, {zone}, {schedule}, EquipmentLevel,\n"
            f"  {watts:.6g}, , , 0, {shape['radiant_fraction']:g}, 0;\n"
            f"Schedule:Compact, {schedule}, , Through: 12/31,\n  {_compact_rules(shape)};\n")


def _airing_text(name: str, schedule: str, zone: str, flow: float, shape: dict) -> str:
    return (f"! bench truth: {flow:.6g} m3/s of outdoor air on {shape['days']}, "
            f"{shape['start_hour']}-{shape['end_hour']} h\n"
            f"ZoneVentilation:DesignFlowRate, {name}, {zone}, {schedule}, Flow/Zone,\n"
            f"  {flow:.6g}, , , , Natural, 0, 1, 1, 0, 0, 0;\n"
            f"Schedule:Compact, {schedule}, , Through: 12/31,\n  {_compact_rules(shape)};\n")


def _aperture_text(name: str, schedule: str, zone: str, area: float, radiant: float,
                   csv: str, plane: str) -> str:
    return (f"! bench truth: sunlit aperture of {area:.6g} m2 on the {plane} plane\n"
            f"OtherEquipment, {name}, None, {zone}, {schedule}, EquipmentLevel,\n"
            f"  {area:.6g}, , , 0, {radiant:g}, 0;\n"
            f"Schedule:File, {schedule}, , {csv}, 2, 1, 8760, Comma, No, 60, No;\n")


def write_irradiance(path: Path, irradiance: np.ndarray) -> Path:
    """The aperture's schedule file: a header row, then weather-file row and W/m² per hour."""
    rows = np.column_stack([np.arange(1, len(irradiance) + 1), irradiance])
    np.savetxt(path, rows, fmt=("%d", "%.6g"), delimiter=",", header="row,irradiance_w_m2",
               comments="")
    return path


def _infiltration_text(name: str, schedule: str, zone: str, coefficients: dict) -> str:
    a, b, c, d = (coefficients[t] for t in INFILTRATION_TERMS)
    return (f"! bench truth: leak law A {a:.4g} + B {b:.4g} |dT| + C {c:.4g} V + D {d:.4g} V2\n"
            f"ZoneInfiltration:DesignFlowRate, {name}, {zone}, {schedule}, Flow/Zone,\n"
            f"  1.0, , , , {a:.6g}, {b:.6g}, {c:.6g}, {d:.6g};\n"
            f"Schedule:Constant, {schedule}, , 1.0;\n")


def _mass_text(name: str, material: str, construction: str, zone: str, area: float,
               thickness: float) -> str:
    k, rho, cp = CONCRETE
    return (f"! bench truth: {area:.6g} m2 of {thickness:g} m concrete inside the zone\n"
            f"Material, {material}, MediumRough, {thickness:g}, {k:g}, {rho:g}, {cp:g}, "
            f"0.9, 0.65, 0.65;\n"
            f"Construction, {construction}, {material};\n"
            f"InternalMass, {name}, {construction}, {zone}, , {area:.6g};\n"
            # a fixed inside coefficient: the test cell gives each surface its own
            # convection curve, and the surrogate needs one for the mass too
            f"SurfaceProperty:ConvectionCoefficients, {name}, Inside, Value, 3.5;\n")


# --------------------------------------------------------------------------- running


def user_config(truth: Truth, directory: Path) -> Path:
    """The user's config for ``truth``: the shipped one with the period and setpoints moved."""
    from bpsflow.config import load_config

    config_path, _, days = MODELS[truth.model]
    config = load_config(config_path)
    test = config.model.tests[0]
    period = next(p for p in config.model.periods if p.name == test.period)
    first = date(config.model.year, *truth.start)
    last = first + timedelta(days=days - 1)
    raw_test = {k: v for k, v in test.model_dump().items() if v is not None}
    raw_test.update(start=f"{first:%m-%d}", days=days, setpoint_c=truth.setpoint_c)
    for key in ("setback_c", "setback_start_hour", "setback_end_hour"):
        raw_test.pop(key, None)
    if truth.setback is not None:
        raw_test.update(setback_c=truth.setback[0], setback_start_hour=truth.setback[1],
                        setback_end_hour=truth.setback[2])
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "user.yaml"
    path.write_text(yaml.safe_dump({
        "extends": str(config_path),
        "model": {"periods": [{"name": period.name, "start": f"{first:%m-%d}",
                               "end": f"{last:%m-%d}"}], "tests": [raw_test]},
        "execution": {"run_dir": str(directory / "user_run")}}, sort_keys=False))
    return path


def _synth_clean(config_path: Path, values: dict, output: str, directory: Path,
                 backend: str):
    """Noise-free measurements of one config (its output column as a frame)."""
    from bpsflow.config import load_config
    from bpsflow.measured import read_measured
    from bpsflow.synth import load_truth, synthesize

    truth_path = directory / f"{config_path.stem}_values.yaml"
    truth_path.write_text(yaml.safe_dump({
        "seed": 0, "values": values,
        "noise": {output: {"kind": "relative", "bound": 0.0}}}, sort_keys=False))
    config = load_config(config_path)
    out = directory / "run" / config_path.stem
    synthesize(config, load_truth(truth_path, config), out, backend=backend)
    return read_measured(out / "measured.csv", config).frame


#: Per backend: the measured anchor's effect-to-level ratio (see :func:`anchor_ratio`).
_ANCHORS: dict[str, float] = {}
#: Per backend: the share of the anchor's effect the fitted inputs cannot absorb.
_ANCHOR_SHARES: dict[str, float] = {}


def unabsorbed_shares(truth: Truth, base: Path, directory: Path, plain: np.ndarray,
                      changes: list[np.ndarray]) -> list[float]:
    """Per effect, the share of its hourly variation that refitting the existing inputs cannot mimic.

    Each of ``changes`` is an effect's change of the diagnosed output (noise-free,
    every evaluated hour). The existing parameters the diagnosis fits first
    (:func:`bpsflow.diagnosis.workflow.fitted_parameters`) each move the
    output along their own sensitivity (a finite difference of 2 % of the
    parameter's range at the truth's values), and the offset along a
    constant; the effect's part outside the span of those columns, on the
    calibration hours, over its own std, is the share left in the residuals
    for a diagnosis to find (1: nothing absorbed; 0: an existing input
    reproduces it exactly). An analysis column: the drawn sizes are not
    changed by it.
    """
    from bpsflow.config import load_config
    from bpsflow.diagnosis.fitting import parameter_range
    from bpsflow.diagnosis.workflow import fitted_parameters

    config = load_config(base)
    values = _truth_values(truth)
    output = config.diagnosis.output
    calibration = np.arange(len(plain)) < len(plain) - 24 * config.diagnosis.holdout_days
    columns = [np.ones(int(calibration.sum()))]
    for parameter in fitted_parameters(config, config.diagnosis):
        low, high = parameter_range(parameter)
        step = 0.02 * (high - low)
        now = float(values.get(parameter.name,
                               parameter.distribution.ppf(np.array([0.5]))[0]))
        moved = {**values, parameter.name: now + step if now + step <= high else now - step}
        folder = directory / f"sensitivity_{parameter.name}"
        folder.mkdir(parents=True, exist_ok=True)
        frame = _synth_clean(base, moved, output, folder, truth.backend)
        columns.append((frame[output].to_numpy(dtype=float) - plain)[calibration])
    design = np.column_stack(columns)
    shares = []
    for change in changes:
        effect = change[calibration]
        coefficients, *_ = np.linalg.lstsq(design, effect, rcond=None)
        spread = float(np.std(effect))
        shares.append(float(np.std(effect - design @ coefficients) / spread) if spread > 0
                      else float("nan"))
    return shares


def anchor_ratio(backend: str, work: Path) -> float:
    """Hourly std of the wind leak at its detection limit over the mean output, on ``backend``.

    The shipped scenario of the detection sweep (configs/diagnosis.yaml as it
    is), with and without ``ZoneInfiltration:DesignFlowRate`` of C =
    :data:`WIND_LIMIT_M3S_PER_MS`, noise-free. The sensor noise is relative,
    so an effect is as detectable as the wind leak at its limit when its std
    over the mean output is this ratio. Measured once per backend and run.
    """
    if backend not in _ANCHORS:
        s = WIND_LIMIT_SCENARIO
        anchor = Truth(-1, "infiltration", "test_cell", backend, s["start"], s["setpoint_c"],
                       None, 0.0, 0, [])
        # one folder per process: truths diagnosed in parallel each measure their own anchor
        directory = work / f"anchor_{backend}_{os.getpid()}"
        base = user_config(anchor, directory)
        zone = build_truth(anchor).zone
        leak = _infiltration_text("bpsflow_bench_anchor", "bpsflow_bench_anchor_always", zone,
                                  {"A": 0.0, "B": 0.0, "C": WIND_LIMIT_M3S_PER_MS, "D": 0.0})
        plain, with_leak = _plain_and_with(anchor, base, directory, [leak])
        _ANCHORS[backend] = float(np.std(with_leak[0] - plain) / np.mean(np.abs(plain)))
        (_ANCHOR_SHARES[backend],) = unabsorbed_shares(anchor, base, directory, plain,
                                                       [with_leak[0] - plain])
        print(f"detection-limit anchor on the {backend}: wind leak std / mean output = "
              f"{_ANCHORS[backend]:.4f}", flush=True)
    return _ANCHORS[backend]


def _truth_values(truth: Truth) -> dict:
    return yaml.safe_load(MODELS[truth.model][1].read_text())["values"]


def _plain_and_with(truth: Truth, base: Path, directory: Path,
                    texts: list[str]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Noise-free output of the user's model, and of it plus each of ``texts`` alone."""
    from bpsflow.config import load_config

    output = load_config(base).diagnosis.output
    values = _truth_values(truth)
    plain = _synth_clean(base, values, output, directory, truth.backend)[output]
    extended = []
    for number, text in enumerate(texts):
        config_path = _truth_config(base, directory, f"alone_{number}", text, {})
        frame = _synth_clean(config_path, values, output, directory, truth.backend)
        extended.append(frame[output].to_numpy(dtype=float))
    return plain.to_numpy(dtype=float), extended


def _truth_config(base: Path, directory: Path, label: str, text: str,
                  files: dict[str, np.ndarray]) -> Path:
    """``base`` plus the hidden objects ``text`` (and the schedule files they read)."""
    raw: dict = {"extends": str(base), "execution": {"run_dir": str(directory / "run")}}
    if text:
        (directory / f"{label}.idf").write_text(text)
        # a child's idf_objects are appended to its parent's
        raw["model"] = {"idf_objects": [f"{label}.idf"]}
    for name, column in files.items():
        write_irradiance(directory / name, column)
    path = directory / f"{label}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def synthesise(truth: Truth, base: Path, directory: Path, work: Path, *,
               noise_bound: float = NOISE_BOUND) -> tuple:
    """Measurements of the truth model (user config + hidden objects), sized on the backend.

    Each effect is first sized by the bench's own physics (:func:`build_truth`),
    then run alone on the backend, noise-free, against the user's model with
    the same (true) fitted inputs: its hourly std over the mean output, over
    the anchor's (:func:`anchor_ratio`), is its *realised* multiple of the
    detection limit. The effect is rescaled so that the realised multiple is
    the drawn one (effects are close to linear in their size; a mass is not
    quite), the truth runs with every effect, and AR(1) sensor noise
    (``truth.phi``, ``noise_bound``) is added. A truth whose effect the backend
    does not simulate at all (an object it ignores) is :class:`TruthUnsupported`.

    Returns
    -------
    frame : DataFrame
        The noisy measurements.
    built : Built
        The truth as run (sizes after rescaling).
    realised : list of float or None
        Each effect's realised multiple before rescaling, over the drawn one
        (1 = the bench's own physics sized it right; ``None`` for nulls).
    """
    from bpsflow.config import load_config
    from bpsflow.simulation.idf import parse_idf_text
    from bpsflow.synth import Noise, add_noise

    output = load_config(base).diagnosis.output
    built = build_truth(truth)
    if truth.backend == "surrogate" and built.text:
        from bpsflow.surrogate.support import unsupported_features

        lacking = unsupported_features(load_config(
            _truth_config(base, directory, "hidden", built.text, built.files)))
        if lacking:
            raise TruthUnsupported("; ".join(lacking))
    realised = None
    if built.text:
        for name, column in built.files.items():
            write_irradiance(directory / name, column)
        plain, alone = _plain_and_with(truth, base, directory, built.parts)
        anchor = anchor_ratio(truth.backend, work)
        realised, scales = [], []
        for effect, text, series in zip(truth.effects, built.parts, alone):
            ratio = float(np.std(series - plain) / np.mean(np.abs(plain)))
            multiple = ratio / anchor
            if multiple < 0.01:
                kinds = sorted({o.type for o in parse_idf_text(text).objects})
                raise TruthUnsupported(
                    f"the hidden {', '.join(kinds)} change {output} by "
                    f"{np.std(series - plain):.3g} W (std) on the {truth.backend}: it does not "
                    f"simulate them")
            if multiple < REALISED_FLOOR * effect.multiple:
                # rescaling would make a physically absurd truth (a gain of hundreds of kW)
                # out of an effect this output barely sees in this scenario
                raise TruthUnsupported(
                    f"the hidden effect realises {multiple / effect.multiple:.3g} of the size "
                    f"the bench's own physics gave it on {output} (floor {REALISED_FLOOR}): "
                    f"it barely reaches this output in this scenario")
            realised.append(round(multiple / effect.multiple, 3))
            scales.append(effect.multiple / multiple)
        built = build_truth(truth, scales)
        shares = unabsorbed_shares(truth, base, directory, plain,
                                   [series - plain for series in alone])
        anchor_share = _ANCHOR_SHARES[truth.backend]
        for effect, size, share in zip(truth.effects, built.sizes, shares):
            size["unabsorbed_share"] = round(share, 3)
            # the drawn multiple counted on the part the fitted inputs leave, against the
            # anchor's own such part
            size["unabsorbed_multiple"] = round(effect.multiple * share / anchor_share, 3)
    config_path = _truth_config(base, directory, "hidden", built.text, built.files)
    frame = _synth_clean(config_path, _truth_values(truth), output, directory, truth.backend)
    noisy = add_noise(frame[output].to_numpy(dtype=float),
                      Noise(kind="relative", bound=noise_bound, autocorrelation=truth.phi),
                      np.random.default_rng(truth.noise_seed)) if noise_bound else frame[output]
    return frame.assign(**{output: noisy}), built, realised


#: The least share of its own-physics size an effect must realise on the backend to be rescaled.
REALISED_FLOOR = 0.1


class TruthUnsupported(Exception):
    """The backend cannot simulate the truth (not the diagnosis's failure)."""


def family_of(extension: str | None) -> str | None:
    if extension is None:
        return None
    for family, names in FAMILY_EXTENSIONS.items():
        if extension in names:
            return family
    return extension


def _relative(fitted: float, true: float) -> float:
    return abs(fitted - true) / abs(true) if true else float("nan")


def _week_mask(day_flags: tuple[int, ...], start_hour: int, end_hour: int) -> np.ndarray:
    """Hours of a week (7 × 24, Monday first) an on/off block is on."""
    hours = np.arange(24)
    return np.outer(np.asarray(day_flags, dtype=bool), (hours >= start_hour) & (hours < end_hour))


#: A week from Monday to Sunday, to lay a drawn gain's schedule on.
_ONE_WEEK = [date(2024, 1, 1) + timedelta(days=i) for i in range(7)]


def _stacked_gain_w(entries: list[dict], size: dict) -> float:
    """The mean gain several accepted blocks add over the true gain's hours (W).

    A gain split by the diagnosis into blocks (two overlapping blocks of
    different radiant fraction, or neighbouring hours) is one effect: each
    block's W counts over the true hours it covers.
    """
    from bpsflow.diagnosis.extensions import DAY_TYPES

    truth = _gain_schedule_values(size, _ONE_WEEK[0].year, _ONE_WEEK).reshape(7, 24) > 0
    stacked = np.zeros((7, 24))
    for entry in entries:
        block, watts = entry.get("schedule") or {}, (entry.get("fitted") or {}).get(
            SIZE_KEYS["gain"][0])
        if watts is None or "day_type" not in block:
            continue
        stacked += float(watts) * _week_mask(DAY_TYPES[block["day_type"]], block["start_hour"],
                                             block["end_hour"])
    return float(stacked[truth].mean()) if truth.any() else float("nan")


def size_errors(built: Built, accepted: list[dict]) -> list[float | None]:
    """Relative size error of each true effect; ``None`` where not comparable.

    Gains (W), apertures (m²) and masses (m²) compare one fitted parameter; an
    infiltration law compares the mean added flow over the evaluated hours
    (fitted terms vs true terms), so that a law fitted with other terms is
    still measured, and only when every fitted infiltration parameter is a
    known term. Several accepted gain blocks are one gain: their W over the
    true hours each covers (:func:`_stacked_gain_w`).
    """
    errors: list[float | None] = []
    for size in built.sizes:
        family = size["family"]
        mine = [e for e in accepted if family_of(e.get("name")) == family]
        fitted: dict = {}
        for e in mine:
            fitted.update(e.get("fitted") or {})
        if not mine:
            errors.append(None)
            continue
        if family == "infiltration":
            by_key = {k: t for t, keys in TERM_KEYS.items() for k in keys}
            if not fitted or any(k not in by_key for k in fitted):
                errors.append(None)
                continue
            flow = sum(float(v) * size["mean_drivers"][by_key[k]] for k, v in fitted.items())
            errors.append(_relative(flow, size["mean_flow_m3s"]))
            continue
        if family == "gain" and len(mine) > 1:
            errors.append(_relative(_stacked_gain_w(mine, size), size["W"]))
            continue
        key = next((k for k in SIZE_KEYS[family] if k in fitted), None)
        true = size[SIZE_UNITS[family]]
        errors.append(None if key is None else _relative(float(fitted[key]), true))
    return errors


#: Compass names of wall azimuths (degrees clockwise from north).
COMPASS = {"north": 0.0, "east": 90.0, "south": 180.0, "west": 270.0}


def facade_right(size: dict, entry: dict) -> bool | None:
    """Whether an accepted aperture's ``facade`` is the true plane; ``None`` if it names none.

    A roof is ``roof``; a wall matches its compass name (within 45°, the
    nearest of north, east, south, west), its azimuth in degrees, or an
    ``azimuth`` field of the entry within 25°.
    """
    facade = str(entry.get("facade") or "").strip().lower()
    azimuth = entry.get("azimuth")
    if not facade and azimuth is None:
        return None
    if size["tilt"] < 45.0:
        return "roof" in facade or "horizontal" in facade
    if isinstance(azimuth, (int, float)):
        return abs((float(azimuth) - size["azimuth"] + 180.0) % 360.0 - 180.0) <= 25.0
    nearest = min(COMPASS, key=lambda c: abs((COMPASS[c] - size["azimuth"] + 180.0) % 360.0
                                             - 180.0))
    return nearest in facade or f"{size['azimuth']:.0f}" in facade


def score(truth: Truth, built: Built | None, result, seconds: float) -> dict:
    """One row: verdict, cause, extension, size errors, held-out gain, wall time."""
    accepted = [e for e in (result.extensions or []) if e.get("accepted")]
    found = [family_of(e.get("name")) for e in accepted]
    reported = family_of(result.cause.get("extension"))
    if result.verdict == "parameter":
        reported = f"parameter:{result.cause.get('parameter')}"
    expected = sorted({e.family for e in truth.effects})
    verdict_ok = result.verdict == ("model_form" if expected else "none")
    # every true family found, and no other: a spurious extension is a wrong cause
    cause_ok = verdict_ok and set(found) == set(expected)
    errors = size_errors(built, accepted) if built else []
    facades = [facade_right(size, e) for size in (built.sizes if built else [])
               if size["family"] == "aperture"
               for e in accepted if family_of(e.get("name")) == "aperture"]
    facade_ok = None if all(f is None for f in facades) else any(f for f in facades)
    for i, size in enumerate(built.sizes if built else []):
        # m² of aperture compare only on the same plane (W per W/m² of that plane)
        if size["family"] == "aperture" and i < len(errors) and all(
                facade_right(size, e) is False for e in accepted
                if family_of(e.get("name")) == "aperture"):
            errors[i] = None
    before, after = result.gain.get("before"), result.gain.get("after")
    fitted = "; ".join(f"{e.get('name')}: " + ", ".join(
        f"{k} = {float(v):.4g}" for k, v in (e.get("fitted") or {}).items())
        + (f" ({e['facade']})" if e.get("facade") else "") for e in accepted)
    return {"case": truth.label, "family": truth.family, "scenario": truth.describe(),
            "truth": _truth_text(built, truth), "verdict": result.verdict,
            "reported": reported or "none", "accepted": [f for f in found if f],
            "fitted": fitted, "verdict_ok": verdict_ok, "cause_ok": cause_ok,
            "multiples": [e.multiple for e in truth.effects],
            "unabsorbed_multiples": [size.get("unabsorbed_multiple")
                                     for size in (built.sizes if built else [])],
            "size_errors": errors, "facade_ok": facade_ok,
            "gain_ratio": (after / before) if before and after is not None else None,
            "cvrmse_before": before, "cvrmse_after": after, "seconds": seconds,
            "backend": truth.backend, "status": "ok", "error": ""}


def _truth_text(built: Built | None, truth: Truth) -> str:
    if not truth.effects:
        return "none"
    if built is None:
        return ", ".join(f"{e.family} ×{e.multiple:g} {e.shape}" for e in truth.effects)
    parts = []
    for size, effect in zip(built.sizes, truth.effects):
        f = size["family"]
        if f == "gain":
            parts.append(f"gain {size['W']:.4g} W {size['days']} {size['start_hour']}-"
                         f"{size['end_hour']} h rad {size['radiant_fraction']:g}")
        elif f == "aperture":
            parts.append(f"aperture {size['m2']:.3g} m² {size['plane']} "
                         f"rad {size['radiant_fraction']:g}")
        elif f == "airing":
            parts.append(f"airing {size['m3s']:.3g} m³/s {size['days']} {size['start_hour']}-"
                         f"{size['end_hour']} h")
        elif f == "infiltration":
            parts.append("leak " + " + ".join(
                f"{t} {c:.3g}" for t, c in size["coefficients"].items() if c))
        else:
            parts.append(f"mass {size['m2']:.3g} m² × {size['thickness_m']:g} m")
        parts[-1] += f" (×{effect.multiple:.2g})"
    return "; ".join(parts)


def failed_row(truth: Truth, built: Built | None, status: str, error: str,
               seconds: float) -> dict:
    return {"case": truth.label, "family": truth.family, "scenario": truth.describe(),
            "truth": _truth_text(built, truth), "verdict": "-", "reported": status,
            "accepted": [], "fitted": "", "verdict_ok": False, "cause_ok": False,
            "multiples": [e.multiple for e in truth.effects], "size_errors": [],
            "facade_ok": None,
            "gain_ratio": None, "cvrmse_before": None, "cvrmse_after": None,
            "seconds": seconds, "backend": truth.backend, "status": status, "error": error}


def run_truth(truth: Truth, work: Path, jobs: int | None = None) -> dict:
    """Synthesise, diagnose and score one truth; any exception is a recorded row."""
    from bpsflow.config import load_config
    from bpsflow.diagnosis.workflow import diagnose

    directory = work / truth.label
    built = None
    try:
        built = build_truth(truth)
        base = user_config(truth, directory)
        frame, built, realised = synthesise(truth, base, directory, work)
        config = load_config(base)
    except TruthUnsupported as exc:
        return failed_row(truth, built, "truth unsupported", str(exc)[:300], 0.0)
    except Exception as exc:                                   # noqa: BLE001
        return failed_row(truth, built, "truth failed", _error(exc), 0.0)
    started = time.perf_counter()
    log = directory / "diagnosis.log"

    def announce(text: str) -> None:
        # the diagnosis's own account of each step, kept to explain a miss afterwards
        with log.open("a", encoding="utf-8") as handle:
            handle.write(text + "\n")

    try:
        result = diagnose(config, frame, directory / "out", backend=truth.backend, jobs=jobs,
                          announce=announce)
    except Exception as exc:                                   # noqa: BLE001
        (directory / "crash.txt").write_text(traceback.format_exc())
        row = failed_row(truth, built, "crash", _error(exc), time.perf_counter() - started)
        row["realised_multiple"] = realised
        return row
    row = score(truth, built, result, time.perf_counter() - started)
    row["realised_multiple"] = realised
    row["diagnosis_json"] = (directory / "out" / "diagnosis.json").is_file()
    return row


def _error(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"[:300]


def run_nulls(count: int, seed: int, work: Path, backend: str = "surrogate",
              per_batch: int = 10, jobs: int | None = None) -> list[dict]:
    """``count`` null datasets, in batches sharing the base fit (one season per batch).

    Each batch draws a season and setpoint regime (as :func:`draw_truths`) and
    ``per_batch`` AR(1) noise series with φ in 0–0.9; the last of each batch
    has φ = 0.9 exactly.
    """
    from bpsflow.config import load_config
    from bpsflow.diagnosis.workflow import diagnose_many
    from bpsflow.synth import Noise, add_noise

    rng = np.random.default_rng([seed, 1])
    rows: list[dict] = []
    batch = 0
    while len(rows) < count:
        size = min(per_batch, count - len(rows))
        truth = draw_truths(1, int(rng.integers(0, 2**31 - 1)), (backend,), ("null",))[0]
        truth.index = 900 + batch
        directory = work / f"nulls_{batch}"
        phis = [round(float(p), 2) for p in rng.uniform(0.0, 0.9, size - 1)] + [0.9]
        try:
            base = user_config(truth, directory)
            clean, _, _ = synthesise(truth, base, directory, work, noise_bound=0.0)
            config = load_config(base)
            output = config.diagnosis.output
            frames = [clean.assign(**{output: add_noise(
                clean[output].to_numpy(dtype=float),
                Noise(kind="relative", bound=NOISE_BOUND, autocorrelation=phi),
                np.random.default_rng([seed, batch, i]))}) for i, phi in enumerate(phis)]
            started = time.perf_counter()
            results = diagnose_many(config, frames,
                                    [directory / f"out_{i}" for i in range(size)],
                                    backend=backend, jobs=jobs, announce=lambda _text: None)
            seconds = (time.perf_counter() - started) / size
            for i, (phi, result) in enumerate(zip(phis, results)):
                truth.phi = phi
                row = score(truth, None, result, seconds)
                row["case"] = f"null_{batch}_{i}"
                rows.append(row)
                _keep(work, "nulls", row)
        except Exception as exc:                               # noqa: BLE001
            (directory / "crash.txt").write_text(traceback.format_exc())
            for i, phi in enumerate(phis):
                truth.phi = phi
                row = failed_row(truth, None, "crash", _error(exc), 0.0)
                row["case"] = f"null_{batch}_{i}"
                rows.append(row)
        print(f"null batch {batch}: {truth.describe()}: "
              f"{sum(r['verdict'] == 'model_form' for r in rows[-size:])} of {size} "
              f"false alarms", flush=True)
        batch += 1
    return rows


# --------------------------------------------------------------------------- summary


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def summarise(rows: list[dict], null_rows: list[dict]) -> dict:
    """Accuracy per family, confusion of causes, size errors, gains, false alarms, crashes."""
    scored = [r for r in rows if r["status"] in ("ok", "crash")]
    effects = [r for r in scored if r["family"] != "null"]
    per_family = {}
    for family in FAMILIES:
        mine = [r for r in scored if r["family"] == family]
        if mine:
            per_family[family] = {"n": len(mine),
                                  "verdict_and_cause": sum(r["cause_ok"] for r in mine) / len(mine)}
    confusion: dict[str, dict[str, int]] = {}
    for r in effects:
        confusion.setdefault(r["family"], {})
        confusion[r["family"]][r["reported"]] = confusion[r["family"]].get(r["reported"], 0) + 1
    big_errors = [e for r in effects for e, m in zip(r["size_errors"], r["multiples"])
                  if e is not None and m >= 3.0]
    gains = [r["gain_ratio"] for r in effects if r["gain_ratio"] is not None]
    # the accuracy is also split by the weakest effect's size (an effect near its limit is
    # missed by design in a share of datasets); the goal is over all sizes
    by_size = {band: [r for r in effects if (min(r["multiples"]) >= 3.0) == big]
               for band, big in (("weakest >= 3x", True), ("weakest < 3x", False))}
    # ... and by the weakest effect's multiple counted on the part the fitted inputs
    # cannot absorb (:func:`unabsorbed_shares`; an analysis, not the goal)
    unabsorbed = [r for r in effects if r.get("unabsorbed_multiples")
                  and None not in r["unabsorbed_multiples"]]
    by_unabsorbed = {band: [r for r in unabsorbed
                            if low <= min(r["unabsorbed_multiples"]) < high]
                     for band, low, high in (("below 1x", 0.0, 1.0), ("1x to 3x", 1.0, 3.0),
                                             ("3x and above", 3.0, math.inf))}
    facades = [r["facade_ok"] for r in effects if r.get("facade_ok") is not None]
    nulls = [r for r in scored if r["family"] == "null"] + null_rows
    by_backend: dict[str, list[float]] = {}
    for r in scored + null_rows:        # a crashed diagnosis's time until the crash counts too
        if r["status"] in ("ok", "crash"):
            by_backend.setdefault(r["backend"], []).append(r["seconds"])
    return {
        "cases": len(rows), "scored": len(scored),
        "unsupported": sum(r["status"] == "truth unsupported" for r in rows),
        "truth_failed": sum(r["status"] == "truth failed" for r in rows),
        "accuracy": sum(r["cause_ok"] for r in scored) / len(scored) if scored else float("nan"),
        "per_family": per_family, "confusion": confusion,
        "accuracy_by_size": {band: {"n": len(mine), "verdict_and_cause":
                                    (sum(r["cause_ok"] for r in mine) / len(mine))
                                    if mine else float("nan")}
                             for band, mine in by_size.items()},
        "accuracy_by_unabsorbed_size": {
            band: {"n": len(mine), "verdict_and_cause":
                   (sum(r["cause_ok"] for r in mine) / len(mine)) if mine else float("nan")}
            for band, mine in by_unabsorbed.items()},
        "median_size_error_3x": _median(big_errors), "size_errors_3x": len(big_errors),
        "median_gain_ratio": _median(gains),
        "aperture_facade_right": (sum(facades) / len(facades)) if facades else float("nan"),
        "aperture_facades_named": len(facades),
        "false_alarm_rate": (sum(r["verdict"] == "model_form" for r in nulls) / len(nulls)
                             if nulls else float("nan")),
        "nulls": len(nulls),
        "crashes": sum(r["status"] == "crash" for r in scored + null_rows),
        "seconds": {b: float(np.mean(s)) for b, s in by_backend.items()},
    }


def markdown(rows: list[dict], null_rows: list[dict], summary: dict, command: str) -> str:
    def pct(v):
        return "-" if v is None else f"{v:.1%}"

    lines = ["# Randomised diagnosis benchmark\n", f"`{command}`\n",
             f"Scored {summary['scored']} of {summary['cases']} truths "
             f"({summary['unsupported']} not simulable on their backend, "
             f"{summary['truth_failed']} truth runs failed); {summary['nulls']} nulls.\n",
             f"- right verdict and cause: {summary['accuracy']:.1%} (goal ≥ 90 %)",
             "- per family: " + ", ".join(f"{f} {v['verdict_and_cause']:.0%} of {v['n']}"
                                           for f, v in summary["per_family"].items()),
             "- by the weakest effect's size (effects only): " + ", ".join(
                 f"{band} {v['verdict_and_cause']:.0%} of {v['n']}"
                 for band, v in summary.get("accuracy_by_size", {}).items()),
             "- by the weakest effect's size on the part the fitted inputs cannot absorb: "
             + (", ".join(f"{band} {v['verdict_and_cause']:.0%} of {v['n']}"
                          for band, v in summary.get("accuracy_by_unabsorbed_size", {}).items()
                          if v["n"]) or "-"),
             "- confusion (truth → reported cause): " + "; ".join(
                 f"{f}: " + ", ".join(f"{c} {n}" for c, n in d.items())
                 for f, d in summary["confusion"].items()),
             f"- median size error, effects ≥ 3× limit: {summary['median_size_error_3x']:.1%} "
             f"over {summary['size_errors_3x']} (goal ≤ 15 %)",
             f"- median held-out CV(RMSE) after/before, effects: "
             f"{summary['median_gain_ratio']:.2f} (goal ≤ 0.5)",
             f"- aperture found on the true plane: {summary['aperture_facade_right']:.0%} of "
             f"{summary['aperture_facades_named']} that name one",
             f"- null false alarms: {summary['false_alarm_rate']:.1%} of {summary['nulls']} "
             f"(goal ≤ 5 %)",
             f"- crashes: {summary['crashes']} (goal 0)",
             "- mean wall time per diagnosis: " + ", ".join(
                 f"{b} {s:.0f} s" for b, s in summary["seconds"].items()), "",
             "| case | scenario | truth | backend ÷ own sizing | unabsorbed × | verdict | "
             "cause (accepted) | fitted | size error | CV(RMSE) before → after | s | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows + null_rows:
        errors = ", ".join("-" if e is None else f"{e:.0%}" for e in r["size_errors"]) or "-"
        mark = "✓" if r["cause_ok"] else "✗"
        facade = {True: ", plane ✓", False: ", plane ✗", None: ""}[r.get("facade_ok")]
        lines.append(
            f"| {r['case']} | {r['scenario']} | {r['truth']} | "
            f"{', '.join(f'{m:.2g}' for m in r.get('realised_multiple') or []) or '-'} | "
            f"{', '.join(f'{m:.2g}' for m in r.get('unabsorbed_multiples') or [] if m is not None) or '-'} | "
            f"{r['verdict']} {mark} | "
            f"{r['reported']} ({', '.join(map(str, r['accepted'])) or '-'}{facade}) | "
            f"{r['fitted'] or '-'} | {errors} | {pct(r['cvrmse_before'])} → "
            f"{pct(r['cvrmse_after'])} | {r['seconds']:.0f} | {r['status']}"
            f"{': ' + r['error'] if r['error'] else ''} |")
    return "\n".join(lines) + "\n"


def _print_row(r: dict) -> None:
    print(f"  {r['case']}: truth {r['truth']} → {r['verdict']} / {r['reported']} {r['fitted']} "
          f"size errors {r['size_errors']} gain {r['gain_ratio']} {r['seconds']:.0f} s "
          f"{r['status']} {r['error']}", flush=True)


def _keep(work: Path, name: str, row: dict) -> None:
    """Append a finished row to ``work/<name>.jsonl``: an interrupted run is still scored."""
    from bpsflow.files import jsonable

    with (work / f"{name}.jsonl").open("a") as stream:
        stream.write(json.dumps(jsonable(row)) + "\n")


def finished_rows(work: Path, name: str) -> list[dict]:
    """The rows :func:`_keep` wrote to ``work/<name>.jsonl`` (none: an empty list)."""
    path = work / f"{name}.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] \
        if path.is_file() else []


def run_truths(truths: list[Truth], work: Path, jobs: int | None = None,
               parallel: int = 1) -> list[dict]:
    """:func:`run_truth` for every truth, in ``parallel`` processes (rows in truth order).

    Each diagnosis on the surrogate runs in one process, so on a machine of
    several cores the truths themselves are the unit of parallel work; on
    EnergyPlus keep ``parallel`` 1 and give the runs ``jobs`` instead. Each
    finished row is also appended to ``work/rows.jsonl`` (:func:`_keep`).
    """
    if parallel <= 1:
        rows = []
        for truth in truths:
            print(f"{truth.label}: {truth.describe()}", flush=True)
            rows.append(run_truth(truth, work, jobs))
            _keep(work, "rows", rows[-1])
            _print_row(rows[-1])
        return rows
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn, not fork: the parent may hold JAX's threads, which a fork would copy half-alive
    context = multiprocessing.get_context("spawn")
    done: dict[int, dict] = {}
    with ProcessPoolExecutor(parallel, mp_context=context) as pool:
        futures = {pool.submit(run_truth, truth, work, jobs): truth for truth in truths}
        for future in as_completed(futures):
            truth = futures[future]
            try:
                done[truth.index] = future.result()
            except Exception as exc:                           # noqa: BLE001
                done[truth.index] = failed_row(truth, None, "crash", _error(exc), 0.0)
            print(f"{truth.label}: {truth.describe()}", flush=True)
            _keep(work, "rows", done[truth.index])
            _print_row(done[truth.index])
    return [done[truth.index] for truth in truths]


def main(count: int, seed: int | None, nulls: int, backends: tuple[str, ...],
         jobs: int | None = None, parallel: int = 1) -> dict:
    """Run the randomised benchmark; print the seed; write the table and the figures."""
    from bpsflow.files import write_json

    from benchlib import scratch

    if seed is None:
        seed = int(time.time_ns() % (2**31 - 1))
    command = (f"python bench/diagnosis_bench.py --random {count} --seed {seed} "
               f"--nulls {nulls} --backends {','.join(backends)}")
    print(f"random diagnosis benchmark: seed {seed} ({command})", flush=True)
    work = scratch("diagnosis-random-")
    write_json(work / "run.json", {"command": command, "seed": seed, "count": count,
                                   "nulls": nulls, "backends": list(backends)})
    rows = run_truths(draw_truths(count, seed, backends), work, jobs, parallel)
    null_rows = run_nulls(nulls, seed, work, "surrogate", jobs=jobs) if nulls else []
    return report(work, rows, null_rows)


def summarise_work(work: Path) -> dict:
    """Score what a run in ``work`` finished (``--summarise``): an interrupted run too.

    The figures say how many of the drawn truths and nulls they cover.
    """
    return report(work, finished_rows(work, "rows"), finished_rows(work, "nulls"))


def report(work: Path, rows: list[dict], null_rows: list[dict]) -> dict:
    """Write the table and the figures of a run's rows (``work/run.json`` says what was drawn)."""
    from bpsflow.files import write_json

    from benchlib import record

    run = json.loads((work / "run.json").read_text())
    command, seed, count = run["command"], run["seed"], run["count"]
    backends = tuple(run["backends"])
    summary = summarise(rows, null_rows)
    # a run on other backends keeps its own table and figures beside the surrogate's
    suffix = "" if backends == ("surrogate",) else "_" + "_".join(backends)
    (ROOT / "bench" / f"diagnosis_random{suffix}.md").write_text(
        markdown(rows, null_rows, summary, command))
    extra: dict = {"seed": seed, "truths": len(rows), "backends": list(backends)}
    if len(rows) < count or len(null_rows) < run["nulls"]:
        extra["partial"] = (f"interrupted: {len(rows)} of {count} truths and "
                            f"{len(null_rows)} of {run['nulls']} null datasets finished")
    record(f"diagnose_random_accuracy{suffix}", summary["accuracy"], "share", ">= 0.90", command,
           per_family=summary["per_family"], confusion=summary["confusion"],
           aperture_facade_right=summary["aperture_facade_right"],
           by_weakest_effect_size=summary["accuracy_by_size"],
           by_weakest_unabsorbed_multiple=summary["accuracy_by_unabsorbed_size"],
           unsupported=summary["unsupported"], **extra)
    record(f"diagnose_random_size_error_3x{suffix}", summary["median_size_error_3x"], "relative",
           "<= 0.15 (median, effects >= 3x the detection limit)", command,
           count=summary["size_errors_3x"], **extra)
    record(f"diagnose_random_gain_ratio{suffix}", summary["median_gain_ratio"], "after/before",
           "<= 0.5 (median held-out CV(RMSE), effect present)", command, **extra)
    record(f"diagnose_random_false_alarm_rate{suffix}", summary["false_alarm_rate"], "share",
           "<= 0.05 over >= 40 nulls", command, nulls=summary["nulls"], **extra)
    record(f"diagnose_random_crashes{suffix}", summary["crashes"], "count", "0", command, **extra)
    record(f"diagnose_random_seconds{suffix}", float(np.mean([s for s in summary["seconds"].values()]))
           if summary["seconds"] else float("nan"), "s",
           "reasonable against 50 s (surrogate) / 24-105 s (EnergyPlus)", command,
           per_backend=summary["seconds"], **extra)
    print(markdown(rows, null_rows, summary, command))
    result = {"command": command, "rows": rows, "nulls": null_rows, "summary": summary,
              "truths": [asdict(t) for t in draw_truths(count, seed, backends)]}
    write_json(work / "random.json", result)
    print(f"rows and truths: {work / 'random.json'}")
    return result
