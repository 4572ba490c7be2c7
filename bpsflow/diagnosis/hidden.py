"""Synthetic "measurements" with a hidden effect, to check that ``diagnose`` finds it.

A truth model is the user's config plus IDF objects the config lacks (a
hidden effect) and, optionally, other parameter values; ``bpsflow synth``
runs it and writes noisy measurements. ``diagnose`` is then given only the
original config and the measurement file: the effect is never named to it.

The effects here are written as plain EnergyPlus objects, independently of
the candidate extensions' snippets (e.g. the internal gain is a weekday
``Schedule:Compact``, which the candidate only approximates by a profile
estimated from the residuals). They act on the zone the matching candidate
extension would be written for (:func:`bpsflow.diagnosis.extensions.diagnosis_zone`:
``diagnosis.extension_zones`` or ``diagnosis.zone``, the diagnosed output's
zone, the model's only zone), or on the zone given, so they fit any model;
their object and schedule names (``bpsflow_hidden_<effect>…``) avoid the
model's names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from bpsflow.config import Config, load_config
from bpsflow.diagnosis.extensions import NAME_PREFIX
from bpsflow.errors import BpsflowError
from bpsflow.files import write_text_atomic

if TYPE_CHECKING:
    from bpsflow.simulation.idf import IdfModel

#: IDF template of each hidden effect. ``{value}`` is the effect's size; ``{zone}`` the
#: zone it acts on; ``{object}`` and ``{schedule}`` the names of the added object and its
#: schedule, and ``{file}`` the schedule's CSV (:func:`render_effect` fills them). The
#: schedules are created here, never assumed to exist in the model.
EFFECTS: dict[str, str] = {
    "wind_infiltration": """
ZoneInfiltration:DesignFlowRate,
    {object}, {zone}, {schedule}, Flow/Zone,
    {value},                 !- Design Flow Rate {m3/s} per m/s of wind
    , , ,
    0, 0, 1, 0;              !- A, B, C (wind), D
Schedule:Constant, {schedule}, , 1;
""",
    "constant_infiltration": """
ZoneInfiltration:DesignFlowRate,
    {object}, {zone}, {schedule}, Flow/Zone,
    {value},                 !- Design Flow Rate {m3/s}
    , , ,
    1, 0, 0, 0;
Schedule:Constant, {schedule}, , 1;
""",
    "office_gain": """
OtherEquipment,
    {object}, None, {zone}, {schedule}, EquipmentLevel,
    {value},                 !- Design Level {W}
    , , 0, 0, 0;
Schedule:Compact,
    {schedule}, ,
    Through: 12/31,
    For: Weekdays, Until: 09:00, 0, Until: 17:00, 1, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 0;
""",
    "east_aperture": """
OtherEquipment,
    {object}, None, {zone}, {schedule}, EquipmentLevel,
    {value},                 !- Design Level {W} per W/m2 (an aperture in m2)
    , , 0, 0, 0;
Schedule:File,
    {schedule}, , {file}, 1, 0, 8760, Comma, No, 60, No;
""",
    "weekend_gain": """
OtherEquipment,
    {object}, None, {zone}, {schedule}, EquipmentLevel,
    {value},                 !- Design Level {W}
    , , 0, 0, 0;
Schedule:Compact,
    {schedule}, ,
    Through: 12/31,
    For: Weekends, Until: 10:00, 0, Until: 16:00, 1, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 0;
""",
    "radiant_evening_gain": """
OtherEquipment,
    {object}, None, {zone}, {schedule}, EquipmentLevel,
    {value},                 !- Design Level {W}
    , , 0,
    0.5,                     !- Fraction Radiant
    0;
Schedule:Compact,
    {schedule}, ,
    Through: 12/31,
    For: Weekdays, Until: 17:00, 0, Until: 22:00, 1, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 0;
""",
    "wind_squared_infiltration": """
ZoneInfiltration:DesignFlowRate,
    {object}, {zone}, {schedule}, Flow/Zone,
    {value},                 !- Design Flow Rate {m3/s} per (m/s)2 of wind
    , , ,
    0, 0, 0, 1;              !- A, B, C, D (wind squared)
Schedule:Constant, {schedule}, , 1;
""",
    "temperature_infiltration": """
ZoneInfiltration:DesignFlowRate,
    {object}, {zone}, {schedule}, Flow/Zone,
    {value},                 !- Design Flow Rate {m3/s} per K of indoor-outdoor difference
    , , ,
    0, 1, 0, 0;              !- A, B (|dT|), C, D
Schedule:Constant, {schedule}, , 1;
""",
    "morning_airing": """
ZoneVentilation:DesignFlowRate,
    {object}, {zone}, {schedule}, Flow/Zone,
    {value},                 !- Design Flow Rate {m3/s} while the windows are open
    , , ,
    Natural, 0, 1,           !- Ventilation Type, Fan Pressure Rise, Fan Total Efficiency
    1, 0, 0, 0;              !- A, B, C, D: the design flow, whatever the weather
Schedule:Compact,
    {schedule}, ,
    Through: 12/31,
    For: Weekdays, Until: 07:00, 0, Until: 09:00, 1, Until: 24:00, 0,
    For: AllOtherDays, Until: 24:00, 0;
""",
    "heavy_mass": """
Material,
    {object}_material, MediumRough,
    0.2,                     !- Thickness (m)
    1.0, 1800, 1000,         !- Conductivity {W/m-K}, Density {kg/m3}, Specific Heat {J/kg-K}
    0.9, 0.65, 0.65;
Construction, {object}_construction, {object}_material;
InternalMass,
    {object}, {object}_construction, {zone}, ,
    {value};                 !- Surface Area {m2}
SurfaceProperty:ConvectionCoefficients, {object}, Inside, Value, 3.0;
""",
}

#: The CSV the east aperture's ``Schedule:File`` reads (written next to the snippet).
EAST_IRRADIANCE_FILE = "hidden_east_irradiance.csv"

#: The drivers a correct diagnosis may name for each effect, and the extension it must choose.
EXPECTED: dict[str, tuple[tuple[str, ...], str]] = {
    "wind_infiltration": (("wind_speed",), "infiltration"),
    "constant_infiltration": (("outdoor_air_temperature",), "infiltration"),
    "office_gain": (("hour_of_day", "weekend"), "internal_gain_schedule"),
    "east_aperture": (("incident_solar_east",), "solar_aperture"),
    "weekend_gain": (("weekend", "hour_of_day"), "internal_gain_schedule"),
    "radiant_evening_gain": (("hour_of_day", "weekend"), "internal_gain_schedule"),
    "wind_squared_infiltration": (("wind_speed",), "infiltration"),
    "temperature_infiltration": (("outdoor_air_temperature",), "infiltration"),
    "heavy_mass": (("hour_of_day", "outdoor_air_temperature"), "thermal_mass"),
    "morning_airing": (("hour_of_day", "weekend"), "scheduled_air_exchange"),
}

#: The extension parameter that measures each effect's size (same units as the effect's value).
MEASURE: dict[str, str] = {
    "wind_infiltration": "infiltration_c_m3s_per_ms",
    "constant_infiltration": "infiltration_a_m3s",
    "office_gain": "scheduled_gain_w",
    "east_aperture": "solar_aperture_m2",
    "weekend_gain": "scheduled_gain_w",
    "radiant_evening_gain": "scheduled_gain_w",
    "wind_squared_infiltration": "infiltration_d_m3s_per_m2s2",
    "temperature_infiltration": "infiltration_b_m3s_per_k",
    "heavy_mass": "internal_mass_area_m2",
    "morning_airing": "scheduled_air_flow_m3s",
}


@dataclass
class HiddenCase:
    """A truth model and the measurements it produced."""

    effect: str | None
    value: float
    measured: Path
    truth_config: Path
    parameter_values: dict[str, float] = field(default_factory=dict)


def render_effect(effect: str, value: float, model: IdfModel, zone: str) -> str:
    """IDF text of the hidden ``effect`` of size ``value`` acting on ``zone`` of ``model``.

    Parameters
    ----------
    effect : str
        A key of :data:`EFFECTS`.
    value : float
        The effect's size, in the unit its template states (m³/s per m/s,
        m³/s, W, or m² of aperture).
    model : IdfModel
        The model the objects are added to: ``zone`` must be one of its
        zones, and the added names avoid all of its names.
    zone : str
        The zone the effect acts on.
    """
    from bpsflow.diagnosis.extensions import fill_template, free_name, model_names, model_zones

    zones = {z.upper(): z for z in model_zones(model)}
    if zone.strip().upper() not in zones:
        raise BpsflowError(f"hidden effect {effect}: the model has no zone '{zone}' (its zones: "
                           f"{', '.join(zones.values())})", source=model.path)
    taken = model_names(model)
    base = f"{NAME_PREFIX}hidden_{effect}"
    return f"! hidden effect {effect}\n" + fill_template(EFFECTS[effect], {
        "value": str(value), "zone": zones[zone.strip().upper()],
        "object": free_name(base, taken), "schedule": free_name(f"{base}_schedule", taken),
        "file": EAST_IRRADIANCE_FILE})


def write_truth(base_config: Path, directory: Path, effect: str | None, value: float,
                parameter_values: dict[str, float], *, seed: int, noise_bound: float = 0.03,
                autocorrelation: float = 0.8, output: str = "heating_power_w",
                zone: str | None = None,
                more_effects: tuple[tuple[str, float], ...] = ()) -> tuple[Path, Path]:
    """Write the truth config (base + hidden effect) and the synth truth file.

    ``noise_bound`` is 3 standard deviations of the relative sensor noise of
    ``output``, AR(1) with lag-1 ``autocorrelation``. The effect acts on
    ``zone``, by default the zone the extension that should find it
    (:data:`EXPECTED`) is written for (:func:`bpsflow.diagnosis.extensions.diagnosis_zone`
    of the base config and ``output``).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    raw: dict = {"extends": str(Path(base_config).resolve()),
                 "execution": {"run_dir": str(directory / "run")}}
    if effect is not None:
        from bpsflow.diagnosis.extensions import diagnosis_zone
        from bpsflow.simulation.idf import model_objects

        config = load_config(base_config)
        model = model_objects(config.model)
        if zone is None:
            zone = diagnosis_zone(config, output, EXPECTED[effect][1], model)
        snippets = []
        for number, (name, size) in enumerate(((effect, value), *more_effects)):
            snippet = directory / f"hidden_effect{number or ''}.idf"
            text = render_effect(name, size, model, zone)
            write_text_atomic(snippet, text)
            snippets.append(snippet.name)
            # the next effect's names must avoid this one's too (a copy: the parsed
            # model is cached)
            from bpsflow.simulation.idf import IdfModel, parse_idf_text

            model = IdfModel(model.path, [*model.objects,
                                          *parse_idf_text(text, snippet).objects])
            if name == "east_aperture":
                _write_east_irradiance(config, directory)
        raw["model"] = {"idf_objects": snippets}
    config_path = directory / "truth_config.yaml"
    write_text_atomic(config_path, yaml.safe_dump(raw, sort_keys=False))
    truth_path = directory / "truth_values.yaml"
    write_text_atomic(truth_path, yaml.safe_dump({
        "seed": int(seed), "values": {k: float(v) for k, v in parameter_values.items()},
        "noise": {output: {"kind": "relative", "bound": float(noise_bound),
                           "autocorrelation": float(autocorrelation)}}}, sort_keys=False))
    return config_path, truth_path


def _write_east_irradiance(config: Config, directory: Path) -> None:
    """The hourly irradiance on a vertical plane facing true east (the driver's plane)."""
    from bpsflow.diagnosis.drivers import derive_drivers
    from bpsflow.diagnosis.extensions import write_schedule, year_hours

    east = derive_drivers(config.model.weather, year_hours(config.model.year))
    write_schedule(east["incident_solar_east"].to_numpy(), directory / EAST_IRRADIANCE_FILE)


def make_case(base_config: Path, directory: Path, effect: str | None, value: float = 0.0,
              parameter_values: dict[str, float] | None = None, *, seed: int = 0,
              backend: str = "surrogate", noise_bound: float = 0.03,
              autocorrelation: float = 0.8, zone: str | None = None,
              more_effects: tuple[tuple[str, float], ...] = ()) -> HiddenCase:
    """Write the truth model and synthesise its measurements (``directory/run/truth``).

    ``zone``: the zone the effect acts on (default: see :func:`write_truth`).
    """
    from bpsflow.synth import load_truth, synthesize

    parameter_values = dict(parameter_values or {})
    config_path, truth_path = write_truth(base_config, directory, effect, value,
                                          parameter_values, seed=seed, noise_bound=noise_bound,
                                          autocorrelation=autocorrelation, zone=zone,
                                          more_effects=more_effects)
    config = load_config(config_path)
    truth = load_truth(truth_path, config)
    out = Path(directory) / "run" / "truth"
    synthesize(config, truth, out, backend=backend)
    return HiddenCase(effect, value, out / "measured.csv", config_path, parameter_values)


def null_measurements(measured: np.ndarray, seeds: list[int], bound: float = 0.03,
                      autocorrelation: float = 0.8) -> list[np.ndarray]:
    """Noisy copies of a noise-free truth series, one per seed (AR(1) relative noise)."""
    from bpsflow.synth import Noise, add_noise

    noise = Noise(kind="relative", bound=bound, autocorrelation=autocorrelation)
    return [add_noise(np.asarray(measured, dtype=float), noise, np.random.default_rng(seed))
            for seed in seeds]
