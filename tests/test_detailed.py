"""Detailed measurements (seed §3.4.3–3.5): sensor model, column contract, physics on EnergyPlus."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from bpsflow import detailed as d
from bpsflow.boundary import ensure_sequences
from bpsflow.cli import app
from bpsflow.config import load_config, period_dates
from bpsflow.errors import BpsflowError
from bpsflow.simulation.idf import parse_idf_text, read_idf
from bpsflow.simulation.rundir import INSTANCE_OUTPUTS, instance_dir
from bpsflow.simulation.setpoints import setpoint_schedules
from bpsflow.synth import load_truth, truth_sample, write_detailed_measurements

from conftest import ROOT, short_raw, write_config

TRUTH = ROOT / "configs" / "i600_truth.yaml"
SURFACES = ["east", "west", "north", "ceiling", "floor"]


# Sensor model -------------------------------------------------------------------

def test_bias_and_std_recovered_from_many_readings():
    errors = d.SensorErrors(bias_c={"a_c": 0.031, "b_c": -0.042}, std_c={"a_c": 0.012, "b_c": 0.019})
    n = 40_000
    true = pd.DataFrame({"a_c": np.full(n, 21.0), "b_c": np.linspace(15, 35, n),
                         "x_w_m2": np.full(n, 400.0), "wall_h_c_w_m2k": np.full(n, 1.7)})
    readings = d.sensor_readings(true, errors, random_state=3)
    for column in ("a_c", "b_c"):
        error = readings[column] - true[column]
        # the mean is the bias within 5 standard errors; a constant's readings scatter with std σ
        assert error.mean() == pytest.approx(errors.bias_c[column], abs=5 * errors.std_c[column] / n ** 0.5)
        assert error.std() == pytest.approx(errors.std_c[column], rel=0.02)
    relative = readings["x_w_m2"] / 400.0 - 1
    assert abs(relative.mean()) < 5 * d.RELATIVE_STD / n ** 0.5
    assert relative.std() == pytest.approx(0.05 / 3, rel=0.02)
    # the derived convection coefficient carries the heat-flux error
    assert (readings["wall_h_c_w_m2k"] / 1.7 - 1).std() == pytest.approx(0.05 / 3, rel=0.02)


def test_sensor_errors_drawn_within_bounds_and_reproducible():
    columns = d.detailed_columns(SURFACES)
    first = d.draw_sensor_errors(columns, [7, 1])
    again = d.draw_sensor_errors(columns, [7, 1])
    other = d.draw_sensor_errors(columns, [8, 1])
    assert list(first.bias_c) == d.temperature_columns(columns)  # every `_c` column, only those
    assert len(first.bias_c) == 45 + 6
    assert first == again and first != other
    bias, std = np.array(list(first.bias_c.values())), np.array(list(first.std_c.values()))
    assert (np.abs(bias) <= d.BIAS_BOUND_C).all() and (std >= 0.01).all() and (std <= 0.02).all()
    with pytest.raises(KeyError, match="no_sensor_c"):
        d.sensor_readings(pd.DataFrame({"no_sensor_c": [1.0]}), first, 0)


def test_calibration_campaign_recovers_bias_and_std_by_eq_11():
    errors = d.draw_sensor_errors(d.detailed_columns(SURFACES), 11)
    campaign = d.calibration_campaign(errors, 12)
    assert len(campaign) == d.CALIBRATION_READINGS
    assert list(campaign.columns[:2]) == ["step", "reference_c"]
    assert campaign["reference_c"].min() == pytest.approx(15.0, abs=0.1)
    assert campaign["reference_c"].max() == pytest.approx(35.0, abs=0.1)
    sensors = list(errors.bias_c)
    difference = campaign[sensors].sub(campaign["reference_c"], axis=0)
    bias_hat = difference.mean()  # eq. 11
    variance_hat = difference.var(ddof=1) - d.REFERENCE_STD_C ** 2
    standard_error = np.sqrt(np.array(list(errors.std_c.values())) ** 2 + d.REFERENCE_STD_C ** 2) \
        / len(campaign) ** 0.5
    assert (np.abs(bias_hat.to_numpy() - np.array(list(errors.bias_c.values())))
            < 5 * standard_error).all()
    assert variance_hat.mean() == pytest.approx(np.mean(np.array(list(errors.std_c.values())) ** 2),
                                                rel=0.15)


# Names and geometry ------------------------------------------------------------------

def test_detailed_outputs_name_the_energyplus_variables(tmp_path):
    config = load_config(write_config(tmp_path, short_raw()))
    outputs = d.detailed_outputs(config)
    assert outputs["ceiling_air_c"].variable == "Surface Inside Face Adjacent Air Temperature"
    assert outputs["ceiling_air_c"].key == "Ceiling"
    assert outputs["wall_thermal_radiation_w_m2"].key == "EastWall"
    assert outputs["south_ground_reflected_w_m2"].key == "SouthWall"
    assert outputs["site_solar_altitude_deg"].key == "Environment"
    assert len(outputs) == 3 * 7 + 7
    raw = short_raw()
    raw["outputs"]["floor_air_c"] = {"variable": "Zone Mean Air Temperature", "key": "Cell"}
    clash = load_config(write_config(tmp_path, raw, name="clash.yaml"))
    with pytest.raises(BpsflowError, match="outputs.floor_air_c"):
        d.detailed_outputs(clash)


def test_span_tests_cover_each_period_and_leave_the_control_alone(tmp_path):
    config = load_config(write_config(tmp_path, short_raw()))
    before = {p.name: setpoint_schedules(config, p) for p in config.model.periods}
    full = config.model_copy(deep=True)
    names = d.add_detailed_outputs(full)
    assert names == ["detailed-winter"]
    span = full.model.tests[0]
    first, last = period_dates(full.period("winter"), full.model.year)
    assert (span.start, span.days, span.mode) == ("12-05", (last - first).days + 1, "free_floating")
    assert set(span.outputs) == set(d.detailed_outputs(config))
    assert [t.name for t in full.model.tests[1:]] == [t.name for t in config.model.tests]
    assert {p.name: setpoint_schedules(full, p) for p in full.model.periods} == before


def test_air_sensor_heights_are_bounded_like_energyplus():
    heights = d.air_sensor_heights(0.0, 3.658, {"ceiling": 3.658, "floor": 0.0, "wall": 1.829})
    assert heights == pytest.approx({"ceiling": 0.99 * 3.658, "floor": 0.01 * 3.658, "wall": 1.829})


def test_cell_geometry_of_the_shipped_model(tmp_path):
    geometry = d.cell_geometry(load_config(write_config(tmp_path, short_raw())))
    assert geometry.room_height_m == pytest.approx(3.658)
    assert geometry.air_sensor_separation_m == pytest.approx(0.98 * 3.658)
    assert geometry.glazed_area_m2 == pytest.approx(6.0)
    assert geometry.south_facade_ground_view_factor == pytest.approx(0.5)
    assert geometry.boundary_surface_names["ceiling"] == ["Ceiling"]
    assert geometry.boundary_sensor_area_m2["east"] == pytest.approx(6.096 * 3.658 / 9)
    assert geometry.boundary_sensor_area_m2["floor"] == pytest.approx(9.144 * 6.096 / 9)


def test_true_values_from_the_truth_file(tmp_path):
    config = load_config(write_config(tmp_path, short_raw(boundary_sequences=400)))
    sample = truth_sample(config, load_truth(TRUTH, config))
    convection = d.true_convection(config, sample)
    assert convection["wall"]["alpha"] == pytest.approx(1.31 * 1.25)
    assert convection["wall"]["n"] == pytest.approx(0.30)
    assert convection["ceiling"]["alpha"] == pytest.approx(0.76 * 0.8)
    assert convection["floor"]["alpha"] == pytest.approx(1.52 * 1.15)
    assert d.true_gradient(config, sample) == pytest.approx(1.4)
    reflectance = d.true_ground_reflectance(config, sample)
    assert len(reflectance) == 12 and list(reflectance.values()) == pytest.approx([0.32] * 12)
    glazing = d.true_glazing(config, sample)
    tau = 0.837 * 0.985
    assert glazing["single_pane_solar_transmittance"] == pytest.approx(tau)
    assert glazing["system_solar_transmittance"] == pytest.approx(
        tau * 0.95 * tau / (1 - 0.075 ** 2))
    # EnergyPlus 25.2 reports this construction (eio WindowConstruction) at 0.649
    assert round(glazing["system_solar_transmittance"], 3) == 0.649


def test_global_horizontal_irradiance_closed_form():
    ghi = d.global_horizontal_irradiance(np.array([800.0, 500.0, 0.0]), np.array([100.0, 50.0, 5.0]),
                                         np.array([30.0, -2.0, 10.0]))
    np.testing.assert_allclose(ghi, [800 * 0.5 + 100, 50.0, 5.0])


# Where the sensors are: chosen from the model's geometry ----------------------------

W, D, H = 8.0, 5.0, 3.0   # synthetic box: x (building east) by y (building north) by z, m
#: Outward faces of the box, vertices counterclockwise seen from outside, upper-left first.
BOX_FACES = {
    "south": ("Wall", [(0, 0, H), (0, 0, 0), (W, 0, 0), (W, 0, H)]),
    "east": ("Wall", [(W, 0, H), (W, 0, 0), (W, D, 0), (W, D, H)]),
    "north": ("Wall", [(W, D, H), (W, D, 0), (0, D, 0), (0, D, H)]),
    "west": ("Wall", [(0, D, H), (0, D, 0), (0, 0, 0), (0, 0, H)]),
    "ceiling": ("Ceiling", [(0, D, H), (0, 0, H), (W, 0, H), (W, D, H)]),
    "floor": ("Floor", [(0, 0, 0), (0, D, 0), (W, D, 0), (W, 0, 0)]),
}
#: Names that say nothing true: the rules must not read them.
MISLEADING = {"south": "EastWall", "east": "NorthWall", "north": "WestWall", "west": "SouthWall",
              "ceiling": "Floor", "floor": "Ceiling"}


def _part(vertices, u0, u1, w0, w1):
    """A rectangle inside a wall: fractions u along its bottom edge, w up its side."""
    top_left, bottom_left, bottom_right = (np.array(v, dtype=float) for v in vertices[:3])
    along, up = bottom_right - bottom_left, top_left - bottom_left
    corners = ((u0, w1), (u0, w0), (u1, w0), (u1, w1))
    return [tuple(bottom_left + u * along + w * up) for u, w in corners]


def box_idf(faces=None, names=None, windows=(("south", 0.3, 0.7, 0.2, 0.8),), rotate_deg=0.0,
            north_axis_deg=0.0, zone_north_deg=0.0, coordinates="World", clockwise=False,
            order=("ceiling", "north", "west", "floor", "east", "south"), zone="Room",
            boundary="Outdoors", extra="") -> str:
    """IDF text of a one-zone box (geometry only): the faces in ``order``, windows on them.

    ``rotate_deg`` turns the vertices clockwise seen from above; ``windows`` are
    (face, u0, u1, w0, w1) rectangles named ``Glass<k>``.
    """
    faces = dict(BOX_FACES if faces is None else faces)
    names = {**{key: key for key in faces}, **(names or {})}
    turn = np.radians(rotate_deg)

    def place(vertices):
        if clockwise:
            vertices = vertices[::-1]
        points = [(x * np.cos(turn) + y * np.sin(turn), -x * np.sin(turn) + y * np.cos(turn), z)
                  for x, y, z in vertices]
        return ",\n    ".join(f"{x:.6f}, {y:.6f}, {z:.6f}" for x, y, z in points)

    entry = "Clockwise" if clockwise else "Counterclockwise"
    text = [f"Building, Box, {north_axis_deg}, Suburbs, 0.04, 0.4, FullExterior, 25, 6;",
            f"GlobalGeometryRules, UpperLeftCorner, {entry}, {coordinates};",
            f"Zone, {zone}, {zone_north_deg};"]
    for key in order:
        kind, vertices = faces[key]
        text.append(f"BuildingSurface:Detailed, {names[key]}, {kind}, Panel, {zone}, , {boundary}, "
                    f", SunExposed, WindExposed, autocalculate, {len(vertices)},\n    "
                    f"{place(vertices)};")
    for k, (key, *fractions) in enumerate(windows):
        text.append(f"FenestrationSurface:Detailed, Glass{k}, Window, Glazing, {names[key]}, , "
                    f"autocalculate, , 1, 4,\n    {place(_part(faces[key][1], *fractions))};")
    return "\n\n".join(text) + "\n" + extra


def select(text: str, settings=None) -> d.SensorSurfaces:
    return d.select_sensor_surfaces(parse_idf_text(text, Path("box.idf")), settings)


def test_sensor_surfaces_of_the_test_cell_are_the_former_names(tmp_path):
    config = load_config(write_config(tmp_path, short_raw()))
    sensors = d.sensor_surfaces(config)
    assert sensors.zone == "Cell"
    assert sensors.surfaces == {"wall": "EastWall", "ceiling": "Ceiling", "floor": "Floor"}
    assert (sensors.window, sensors.facade) == ("SouthWindow", "SouthWall")
    assert sensors.chosen_by == {key: d.RULES[key] for key in d.SETTING_KEYS}
    outputs = d.detailed_outputs(config)
    assert outputs["window_transmitted_w"].key == "SouthWindow"
    assert outputs["floor_surface_c"].key == "Floor"
    meta = d.detailed_metadata(config, d.cell_geometry(config), pd.DataFrame({"step": [0]}))
    assert meta["surface_classes"] == sensors.surfaces
    assert (meta["zone"], meta["window_surface"], meta["south_facade_surface"]) == \
        ("Cell", "SouthWindow", "SouthWall")


def test_outward_normals_and_azimuths_of_the_test_cell():
    idf = read_idf(ROOT / "sample_idf" / "flexlab_x3b.idf")
    assert d.geometry_rules(idf) == (False, True)   # counterclockwise, world coordinates
    azimuths = {s.name: d.azimuth_deg(d.outward_normal(s.vertices()))
                for s in idf.of_type("BuildingSurface:Detailed")}
    assert azimuths == pytest.approx({"SouthWall": 180, "EastWall": 90, "NorthWall": 0,
                                      "WestWall": 270, "Ceiling": 0, "Floor": 0}, abs=1e-9)
    ceiling = idf.find("BuildingSurface:Detailed", "Ceiling")
    np.testing.assert_allclose(d.outward_normal(ceiling.vertices()), [0, 0, 1])
    np.testing.assert_allclose(d.outward_normal(ceiling.vertices(), clockwise=True), [0, 0, -1])
    assert np.linalg.norm(d.newell_normal(ceiling.vertices())) == pytest.approx(2 * 9.144 * 6.096)
    assert d.azimuth_deg((1.0, 0.0, 0.0), north_axis_deg=300.0) == pytest.approx(30.0)


@pytest.mark.parametrize("rotate, north, zone_north, coordinates, clockwise, wall", [
    (0, 0, 0, "World", False, "east"),        # east and west tie; east is first from north
    (0, 0, 0, "World", True, "east"),         # clockwise vertex entry: same outward normals
    (30, 0, 0, "World", False, "east"),       # east face at 120°, west face at 300°
    (90, 0, 0, "World", False, "west"),       # window faces west; the side faces north and south
    (200, 0, 0, "World", False, "west"),      # east face at 290°, west face at 110°
    (0, 180, 0, "Relative", False, "west"),   # the north axis turns the building around
    (0, 90, 90, "Relative", False, "west"),   # building and zone north add up
    (0, 180, 0, "World", False, "east"),      # world coordinates: EnergyPlus ignores the axis
])
def test_sensor_surfaces_follow_orientation_not_names(rotate, north, zone_north, coordinates,
                                                      clockwise, wall):
    sensors = select(box_idf(names=MISLEADING, rotate_deg=rotate, north_axis_deg=north,
                             zone_north_deg=zone_north, coordinates=coordinates,
                             clockwise=clockwise))
    assert sensors.zone == "Room"
    assert sensors.surfaces == {"wall": MISLEADING[wall], "ceiling": MISLEADING["ceiling"],
                                "floor": MISLEADING["floor"]}
    assert (sensors.window, sensors.facade) == ("Glass0", MISLEADING["south"])


def test_sensor_surfaces_rank_glazing_perpendicularity_and_area():
    east = BOX_FACES["east"][1]
    cut = 2 * W / 3
    split = {**BOX_FACES, "east": ("Wall", _part(east, 0, 0.6, 0, 1)),
             "east2": ("Wall", _part(east, 0.6, 1, 0, 1)),
             "ceiling": ("Roof", [(0, D, H), (0, 0, H), (cut, 0, H), (cut, D, H)]),
             "ceiling2": ("Ceiling", [(cut, D, H), (cut, 0, H), (W, 0, H), (W, D, H)])}
    # a split east wall: the whole west wall is larger, which outranks being first from north
    sensors = select(box_idf(split, order=("east", "east2", "west", "north", "south", "ceiling2",
                                           "ceiling", "floor")))
    assert sensors.surfaces["wall"] == "west"
    assert sensors.surfaces["ceiling"] == "ceiling"   # a Roof counts; the larger part wins
    # the largest exterior window is measured; walls with glazing are passed over, and of the
    # others the one perpendicular to the measured window's facade wins
    windows = (("east", 0.4, 0.6, 0.4, 0.6), ("north", 0.2, 0.8, 0.2, 0.8))
    sensors = select(box_idf(windows=windows))
    assert (sensors.window, sensors.facade) == ("Glass1", "north")
    assert sensors.surfaces["wall"] == "west"
    # glazing to an adiabatic neighbour is not an exterior window
    interior = select(box_idf(boundary="Adiabatic"))
    assert interior.window is None
    with pytest.raises(BpsflowError, match=r"exterior window in zone 'Room'.*detailed\.window"):
        interior.glazing()
    assert select(box_idf(boundary="Adiabatic"), {"window": "glass0"}).window == "Glass0"


def test_several_zones_need_the_zone_key():
    annex = ("Zone, Annex;\nBuildingSurface:Detailed, AnnexFloor, Floor, Panel, Annex, , Ground, , "
             "NoSun, NoWind, 0, 4, 20, 0, 0, 20, 5, 0, 28, 5, 0, 28, 0, 0;\n")
    text = box_idf(extra=annex)
    with pytest.raises(BpsflowError, match=r"2 zones \(Room, Annex\); set detailed\.zone"):
        select(text)
    assert select(text, {"zone": "room"}).surfaces["wall"] == "east"
    with pytest.raises(BpsflowError, match=r"detailed\.zone: the model has no zone 'Hall'; "
                                           r"its zones: Room, Annex"):
        select(text, {"zone": "Hall"})
    with pytest.raises(BpsflowError, match=r"zone 'Annex' has no .*Surface Type Wall"):
        select(text, {"zone": "Annex"})


def test_config_names_surfaces_and_the_zone(tmp_path):
    raw = short_raw()
    raw["detailed"] = {"wall": "westwall", "window": "SouthWindow"}
    config = load_config(write_config(tmp_path, raw))
    sensors = d.sensor_surfaces(config)
    assert sensors.surfaces["wall"] == "WestWall" and sensors.chosen_by["wall"] == "detailed.wall"
    assert sensors.chosen_by["window"] == "detailed.window"
    assert d.detailed_outputs(config)["wall_surface_c"].key == "WestWall"
    assert d.true_convection(config, {p.name: p.distribution.ppf(np.array([0.5]))[0]
                                      for p in config.parameters})["wall"]["surface"] == "WestWall"
    raw["detailed"] = {"wall": "Ceiling"}
    config = load_config(write_config(tmp_path, raw, name="bad.yaml"))
    with pytest.raises(BpsflowError, match=r"bad\.yaml: detailed\.wall: 'Ceiling' .*it is a "
                                           r"Ceiling.*expected one of: SouthWall, EastWall, "
                                           r"NorthWall, WestWall"):
        d.detailed_outputs(config)
    raw["detailed"] = {"door": "SouthWindow"}
    with pytest.raises(BpsflowError, match=r"detailed\.door"):
        load_config(write_config(tmp_path, raw, name="unknown.yaml"))


def test_a_second_zone_in_a_snippet_asks_for_the_zone_key(tmp_path):
    snippet = tmp_path / "annex.idf"
    snippet.write_text("Zone, Annex;\nBuildingSurface:Detailed, AnnexFloor, Floor, Panel, Annex, , "
                       "Ground, , NoSun, NoWind, 0, 4, 20, 0, 0, 20, 5, 0, 28, 5, 0, 28, 0, 0;\n")
    raw = short_raw(boundary_sequences=400)
    raw["model"]["backend"] = "surrogate"
    raw["model"]["idf_objects"] = [str(snippet)]
    path = write_config(tmp_path, raw)
    result = CliRunner().invoke(app, ["synth", str(path), "--truth", str(TRUTH), "--detailed",
                                      "--out", str(tmp_path / "truth")])
    assert result.exit_code != 0
    assert "detailed.zone" in " ".join(result.output.split()) and "Annex" in result.output
    raw["detailed"] = {"zone": "Cell"}
    config = load_config(write_config(tmp_path, raw, name="zoned.yaml"))
    assert d.sensor_surfaces(config).surfaces == {"wall": "EastWall", "ceiling": "Ceiling",
                                                  "floor": "Floor"}


# Files: from true outputs to readings, without EnergyPlus ---------------------------------

@pytest.fixture
def written(tmp_path):
    """Detailed files from made-up true outputs of the short case (no simulation)."""
    config = load_config(write_config(tmp_path, short_raw(boundary_sequences=400)))
    ensure_sequences(config)
    sample = truth_sample(config, load_truth(TRUTH, config))
    first, last = period_dates(config.period("winter"), config.model.year)
    stamps = pd.date_range(pd.Timestamp(first) + pd.Timedelta(hours=1),
                           pd.Timestamp(last) + pd.Timedelta(days=1), freq="h")
    rng = np.random.default_rng(5)
    frames = []
    for name, spec in d.detailed_outputs(config).items():
        level = {"C": 22.0, "deg": 20.0}.get(spec.unit, 150.0)
        frames.append(pd.DataFrame({"instance": "truth", "test": "detailed-winter", "output": name,
                                    "timestamp": stamps,
                                    "value": level + rng.uniform(1, 10, len(stamps))}))
    outputs = pd.concat(frames, ignore_index=True)
    truth = write_detailed_measurements(config, sample, outputs, 17, tmp_path / "out")
    wide = outputs.pivot(index="timestamp", columns="output", values="value")
    return config, sample, wide, truth, tmp_path / "out"


def test_written_files_keep_the_column_contract(written):
    config, _, wide, _, out = written
    readings = d.read_detailed(out / d.DETAILED_FILE)
    assert list(readings.columns) == d.detailed_columns(SURFACES)
    assert len(readings) == len(wide) and (readings.index == wide.index).all()
    calibration = d.read_calibration(out / d.CALIBRATION_FILE)
    assert list(calibration.columns) == ["step", "reference_c"] + d.temperature_columns(readings.columns)
    meta = json.loads((out / d.METADATA_FILE).read_text())
    for key in ("air_sensor_separation_m", "glazed_area_m2", "south_facade_ground_view_factor",
                "reference_sensor_std_c", "irradiance_relative_std", "boundary_sensor_area_m2",
                "surface_classes", "sensor_error_model"):
        assert key in meta
    assert list(meta["boundary_sensor_area_m2"]) == SURFACES
    # window transmitted per glazed area; h with its relative error only
    ratio = readings["window_transmitted_w_m2"] / (wide["window_transmitted_w"] / 6.0)
    assert abs(ratio.mean() - 1) < 0.01
    assert abs((readings["floor_h_c_w_m2k"] / wide["floor_h_c_w_m2k"]).mean() - 1) < 0.01


def test_calibration_and_readings_share_each_sensors_bias(written):
    config, sample, wide, truth, out = written
    readings = d.read_detailed(out / d.DETAILED_FILE)
    calibration = d.read_calibration(out / d.CALIBRATION_FILE)
    boundary = d.true_boundary_temperatures(config, sample, readings.index)
    sensors = truth["sensors"]
    standardised = []
    for surface in SURFACES:
        for column in d.boundary_columns([surface]):
            bias_hat = (calibration[column] - calibration["reference_c"]).mean()  # eq. 11
            corrected = readings[column] - bias_hat
            # a sensor corrected by its own calibration reads the true boundary temperature
            assert abs((corrected - boundary[surface]).mean()) < 0.01
            standardised.append((readings[column] - sensors[column]["bias_c"] - boundary[surface])
                                / sensors[column]["std_c"])
    pooled = np.concatenate(standardised)
    assert abs(pooled.mean()) < 5 / len(pooled) ** 0.5
    assert pooled.std() == pytest.approx(1.0, rel=0.05)
    relative = np.concatenate([(readings[f"{c}_conduction_w_m2"] / wide[f"{c}_conduction_w_m2"] - 1)
                               for c in d.SURFACE_CLASSES])
    assert relative.std() == pytest.approx(0.05 / 3, rel=0.15)
    radiation = wide["ceiling_thermal_radiation_w_m2"] + wide["ceiling_solar_radiation_w_m2"]
    assert abs((readings["ceiling_radiation_w_m2"] / radiation).mean() - 1) < 0.01


def test_read_detailed_names_the_missing_column_and_the_bad_row(written, tmp_path):
    *_, out = written
    frame = pd.read_csv(out / d.DETAILED_FILE)
    broken = tmp_path / "broken" / d.DETAILED_FILE
    broken.parent.mkdir()
    frame.drop(columns=["floor_air_c"]).to_csv(broken, index=False)
    with pytest.raises(BpsflowError, match=r"floor_air_c"):
        d.read_detailed(broken)
    frame.drop(columns=["boundary_north_s4_c"]).to_csv(broken, index=False)
    with pytest.raises(BpsflowError, match=r"boundary_north_s4_c"):
        d.read_detailed(broken, surfaces=SURFACES)
    bad = frame.copy()
    bad.loc[3, "timestamp"] = "not a time"
    bad.to_csv(broken, index=False)
    with pytest.raises(BpsflowError, match=r"row 5: timestamp 'not a time'"):
        d.read_detailed(broken)
    with pytest.raises(BpsflowError, match="not found"):
        d.read_detailed(tmp_path / "nowhere.csv")


# One real EnergyPlus run -------------------------------------------------------------

@pytest.mark.energyplus
def test_energyplus_truth_carries_the_physics(tmp_path):
    raw = short_raw(boundary_sequences=400)
    raw["model"]["periods"] = [{"name": "winter", "start": "12-05", "end": "12-06"}]
    raw["model"]["tests"] = [raw["model"]["tests"][0]]  # H-ST: 2 days, 1 warm-up
    path = write_config(tmp_path, raw)
    out = tmp_path / "truth"
    result = CliRunner().invoke(app, ["synth", str(path), "--truth", str(TRUTH), "--detailed",
                                      "--backend", "energyplus", "--out", str(out)])
    assert result.exit_code == 0, result.output
    readings = d.read_detailed(out / d.DETAILED_FILE)
    assert len(readings) == 48
    assert (readings.index[0], readings.index[-1]) == (pd.Timestamp("2025-12-05 01:00"),
                                                       pd.Timestamp("2025-12-07 00:00"))
    meta = json.loads((out / d.METADATA_FILE).read_text())
    truth = json.loads((out / "truth.json").read_text())["detailed"]
    # the truth instance's own outputs, where synth's ensemble run left them
    tidy = pd.read_parquet(instance_dir(out / "simulation", 0) / INSTANCE_OUTPUTS)
    true = (tidy.drop_duplicates(["timestamp", "output"])
            .pivot(index="timestamp", columns="output", values="value"))

    for c in d.SURFACE_CLASSES:  # eq. 15 closes on the true values
        balance = (true[f"{c}_convection_w_m2"] + true[f"{c}_conduction_w_m2"]
                   + true[f"{c}_thermal_radiation_w_m2"] + true[f"{c}_solar_radiation_w_m2"])
        assert balance.abs().max() < 0.01
        radiation = true[f"{c}_thermal_radiation_w_m2"] + true[f"{c}_solar_radiation_w_m2"]
        error = readings[f"{c}_radiation_w_m2"] - radiation
        assert (error.abs() <= 6 * d.RELATIVE_STD * radiation.abs() + 1e-9).all()

    # eq. 18 over the air-sensor separation recovers the true gradient
    gradient = (true["ceiling_air_c"] - true["floor_air_c"]) / meta["air_sensor_separation_m"]
    assert (gradient - truth["stratification_gradient_k_m"]).abs().max() < 1e-3
    sensors = truth["sensors"]
    corrected = ((readings["ceiling_air_c"] - sensors["ceiling_air_c"]["bias_c"])
                 - (readings["floor_air_c"] - sensors["floor_air_c"]["bias_c"]))
    assert abs(corrected.mean() / meta["air_sensor_separation_m"] - 1.4) < 0.005

    # ground reflected on the south facade (view factor 1/2) over global horizontal
    ghi = d.global_horizontal_irradiance(true["site_direct_w_m2"], true["site_diffuse_w_m2"],
                                         true["site_solar_altitude_deg"])
    daylight = ghi >= 50.0
    assert daylight.sum() >= 10
    estimate = true["south_ground_reflected_w_m2"] / meta["south_facade_ground_view_factor"] / ghi
    assert ((estimate[daylight] / truth["ground_reflectance"] - 1).abs() < 0.02).all()
    measured = (readings["south_ground_reflected_w_m2"] / meta["south_facade_ground_view_factor"]
                / readings["global_horizontal_w_m2"])
    assert measured[daylight].median() == pytest.approx(truth["ground_reflectance"], rel=0.03)

    # the boundary sensors, bias removed, average to the imposed temperatures
    for surface, record in truth["boundary"].items():
        columns = d.boundary_columns([surface])
        mean = np.mean([readings[c] - sensors[c]["bias_c"] for c in columns])
        assert mean == pytest.approx(record["mean_c"], abs=0.005)


def test_truth_sampler_value_must_index_a_sequence(tmp_path):
    config = load_config(write_config(tmp_path, short_raw(boundary_sequences=20)))
    with pytest.raises(BpsflowError, match=r"values.west_boundary_sampler: 233 .* 0..19"):
        load_truth(TRUTH, config)
