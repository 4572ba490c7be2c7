"""Generate the synthetic "measured" boundary temperatures for flexlab_x3b.idf.

Writes ``boundary_temperatures.csv`` next to this script: one header row and
8760 hourly rows of a non-leap year.  Column 1 is an EnergyPlus-style,
hour-ending timestamp ``MM/DD HH:00`` (``01/01 01:00`` is the hour
00:00-01:00 of 1 January, ``12/31 24:00`` the last hour); it is ignored by
EnergyPlus.  Columns 2..6 are temperatures in degC, read by the
``Schedule:File`` objects ``EastBoundaryTemperature`` (column 2),
``WestBoundaryTemperature`` (3), ``NorthBoundaryTemperature`` (4),
``CeilingBoundaryTemperature`` (5) and ``FloorBoundaryTemperature`` (6).

Model, with t the hour midpoint in hours since 1 January 00:00 and
d = t / 24 the day of year (0-based):

* adjacent spaces (east, west, north, ceiling):

      T = 22.5 - 0.5 cos(2 pi (d - 20) / 365)      seasonal: ~22 C in late
                                                   January, ~23 C in late July
          + offset_k                               ceiling +0.5 K, others 0
          + A_k sin(2 pi (h - 9) / 24)             diurnal swing peaking at
                                                   15:00, A = 0.5/0.6/0.3/0.8 K
                                                   for east/west/north/ceiling
          + drift_k(t)                             slow drift: AR(1) process,
                                                   time constant 72 h, sd 0.3 K
          + noise_k(t)                             small smooth noise: white
                                                   noise (sd 0.08 K) through a
                                                   centred 5 h moving average

* floor: the radiant slab under the floor panel is kept at the temperature the
  room is anticipated to have during the tests, so it follows the tests'
  setpoints: 30 C during the heating test period (05 Dec 00:00 - 22 Dec 24:00)
  and 20 C during the cooling test period (05 Jul 00:00 - 22 Jul 24:00), 22 C
  elsewhere; the change between levels is a linear ramp over the 24 h before
  each period starts and the 24 h after it ends.  A small diurnal swing
  (A = 0.1 K), drift (sd 0.1 K) and the same smooth noise are added.

Everything is deterministic (numpy default_rng with a fixed seed); rerunning
the script reproduces the file byte for byte.
"""

from pathlib import Path

import numpy as np

SEED = 20251205
HOURS = 8760
MONTH_DAYS = (31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31)
COLUMNS = ("east_c", "west_c", "north_c", "ceiling_c", "floor_c")

# per boundary: (mean offset K, diurnal amplitude K, drift sd K)
ADJACENT = {
    "east_c": (0.0, 0.5, 0.3),
    "west_c": (0.0, 0.6, 0.3),
    "north_c": (0.0, 0.3, 0.3),
    "ceiling_c": (0.5, 0.8, 0.3),
}
FLOOR_DIURNAL = 0.1
FLOOR_DRIFT_SD = 0.1
FLOOR_DEFAULT = 22.0
# (first day, last day inclusive, slab temperature); days as (month, day)
FLOOR_TESTS = (((7, 5), (7, 22), 20.0), ((12, 5), (12, 22), 30.0))
RAMP_HOURS = 24.0
DRIFT_TAU_HOURS = 72.0
NOISE_SD = 0.08
NOISE_WINDOW = 5


def day_of_year(month: int, day: int) -> int:
    """0-based day of year in a non-leap year."""
    return sum(MONTH_DAYS[: month - 1]) + day - 1


def timestamps() -> list[str]:
    out = []
    for month, ndays in enumerate(MONTH_DAYS, start=1):
        for day in range(1, ndays + 1):
            for hour in range(1, 25):
                out.append(f"{month:02d}/{day:02d} {hour:02d}:00")
    return out


def ar1(rng: np.random.Generator, sd: float) -> np.ndarray:
    """Stationary AR(1) series with standard deviation sd, time constant tau."""
    phi = np.exp(-1.0 / DRIFT_TAU_HOURS)
    eps = rng.normal(0.0, sd * np.sqrt(1.0 - phi**2), HOURS)
    x = np.empty(HOURS)
    x[0] = rng.normal(0.0, sd)
    for i in range(1, HOURS):
        x[i] = phi * x[i - 1] + eps[i]
    return x


def smooth_noise(rng: np.random.Generator) -> np.ndarray:
    white = rng.normal(0.0, NOISE_SD, HOURS + NOISE_WINDOW - 1)
    kernel = np.ones(NOISE_WINDOW) / NOISE_WINDOW
    return np.convolve(white, kernel, mode="valid")


def floor_level(t: np.ndarray) -> np.ndarray:
    level = np.full(HOURS, FLOOR_DEFAULT)
    for (m0, d0), (m1, d1), temp in FLOOR_TESTS:
        start = day_of_year(m0, d0) * 24.0
        end = (day_of_year(m1, d1) + 1) * 24.0
        # weight 1 inside [start, end], linear ramps over RAMP_HOURS outside
        w = np.clip(
            np.minimum((t - (start - RAMP_HOURS)) / RAMP_HOURS,
                       ((end + RAMP_HOURS) - t) / RAMP_HOURS),
            0.0, 1.0,
        )
        level = level + w * (temp - FLOOR_DEFAULT)
    return level


def generate() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(SEED)
    t = np.arange(HOURS) + 0.5  # hour midpoints
    d = t / 24.0
    hour_of_day = t % 24.0
    seasonal = 22.5 - 0.5 * np.cos(2.0 * np.pi * (d - 20.0) / 365.0)
    diurnal = np.sin(2.0 * np.pi * (hour_of_day - 9.0) / 24.0)
    data = {}
    for name, (offset, amp, drift_sd) in ADJACENT.items():
        data[name] = (seasonal + offset + amp * diurnal
                      + ar1(rng, drift_sd) + smooth_noise(rng))
    data["floor_c"] = (floor_level(t) + FLOOR_DIURNAL * diurnal
                       + ar1(rng, FLOOR_DRIFT_SD) + smooth_noise(rng))
    return data


def main() -> None:
    data = generate()
    lines = ["timestamp," + ",".join(COLUMNS)]
    for i, stamp in enumerate(timestamps()):
        values = ",".join(f"{data[c][i]:.2f}" for c in COLUMNS)
        lines.append(f"{stamp},{values}")
    path = Path(__file__).resolve().parent / "boundary_temperatures.csv"
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


if __name__ == "__main__":
    main()
