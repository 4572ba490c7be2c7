"""The surrogate's stepping loop compiled (numba): one day of steps for every instance.

:meth:`bpsflow.surrogate.network._Stepper.step` states the step in numpy,
vectorised over instances; with the few instances a calibration or
diagnosis fit runs at once, its time goes to numpy's per-call overhead, not
to arithmetic. This module is the same step written per instance and
compiled: the same heat balance, the same order of elimination (chains onto
the air and star hubs, a 2x2 solve, back-substitution), the same ideal air
system. It is used for plain runs; the numpy step remains the reference
(and serves the energy accounting, the face probe and the dense solve).
The two agree to rounding (``tests/test_surrogate.py``). Division follows
numpy's rules (``error_model="numpy"``): a degenerate model gives non-finite
outputs, which the simulation layer reports, not a ``ZeroDivisionError``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from bpsflow.surrogate.forcing import SIGMA

#: The surrogate's constants (both steps use them; numba compiles them in).
KELVIN = 273.15
#: EnergyPlus's lower limit on convection coefficients (W/m²K).
H_MIN = 0.1


@njit(cache=True, error_model="numpy")
def _curve(c1: float, c2: float, c3: float, lower: float, upper: float, x: float) -> float:
    return c1 + c2 * min(max(x, lower), upper) ** c3


@njit(cache=True, error_model="numpy")
def _gap_conductance(t1: float, t2: float, e1: float, e2: float, width: float,
                     pressure: float) -> float:
    """Air gap conductance (W/m²K), as :func:`bpsflow.surrogate.network._gap_conductance`."""
    k1, k2 = t1 + KELVIN, t2 + KELVIN
    radiation = SIGMA * (k1 * k1 + k2 * k2) * (k1 + k2) / (1 / e1 + 1 / e2 - 1)
    mean = 0.5 * (k1 + k2)
    conductivity = 2.873e-3 + 7.760e-5 * mean
    viscosity = 3.723e-6 + 4.94e-8 * mean
    cp = 1002.737 + 1.2324e-2 * mean
    density = pressure * 28.97e-3 / (8.314462 * mean)
    rayleigh = (density ** 2 * width ** 3 * 9.81 * cp * abs(k1 - k2)
                / (viscosity * conductivity * mean))
    nusselt = 0.0 if rayleigh > 1e4 else 1 + 1.7596678e-10 * rayleigh ** 2.2984755
    turbulent = 0.0795 * rayleigh ** 0.31 if rayleigh > 5e4 else 0.028154 * rayleigh ** 0.4134
    nusselt = max(nusselt, turbulent)
    return radiation + max(nusselt, 1.0) * conductivity / width


@dataclass
class KernelConstants:
    """Per-run constants of the compiled step, as contiguous arrays (see :func:`run_day`)."""

    faces: np.ndarray            # (m,) inside-face nodes, the window's room-side pane last
    dz: np.ndarray               # (m,)
    gradient: np.ndarray         # (n,)
    curve: np.ndarray            # (n, m, 3) inside convection c1, c2, c3
    curve_bounds: np.ndarray     # (m, 2)
    face_area: np.ndarray        # (n, m)
    radiant_area: np.ndarray     # (n, m)
    window: np.ndarray           # (n, 4): gap emissivities (out, in), pane resistance, area
    gap_width: float
    pane_out: int
    pane_in: int
    exterior_nodes: np.ndarray   # (x,)
    exterior: np.ndarray         # (n, x, 3): area, emissivity, wind factor
    exterior_view: np.ndarray    # (x, 3): f_sky, f_ground, beta
    outside_wind: np.ndarray     # (n, x, 5): c1, c2, c3, lower, upper
    outside_natural: np.ndarray  # (n, x, 5)
    ventilation: np.ndarray      # (n,) m³/s
    volume: float
    zone_wind_factor: float
    exchange: np.ndarray         # (e, n, 5): design, A, B, C, D
    exchange_outdoor: np.ndarray  # (e,) 1: outdoor-air density, 0: standard
    standard_density: float
    c_dt: np.ndarray             # (n, size)
    static_diagonal: np.ndarray  # (n, size)
    chain_nodes: np.ndarray      # (chains, length), padded at the outside end with ``size``
    chain_start: np.ndarray      # (chains,) first real position
    chain_links: np.ndarray      # (n, chains, length - 1)
    gap_chain: int               # chain and position of the glazing gap link (-1: none)
    gap_position: int
    air_coefficient: float
    air_history: np.ndarray      # (3,)
    dt: float


def run_day(constants: KernelConstants, state: np.ndarray, history: np.ndarray,
            inputs: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One day of steps for every instance; ``history`` (n, 3) is updated in place.

    Returns the end state ``(n, size)``, the air temperature and the ideal
    air system's power per step ``(n, steps)``.
    """
    n, size = state.shape
    steps = inputs["heat"].shape[0]

    def per_instance(name: str) -> np.ndarray:
        return np.ascontiguousarray(np.broadcast_to(inputs[name], (n, steps)), dtype=float)

    internal = inputs["internal"]
    if internal is None:
        internal = np.zeros((1, 1, 1))
    schedules = inputs["exchange_schedules"]
    exchange_schedules = (np.ascontiguousarray(np.stack(schedules), dtype=float) if schedules
                          else np.zeros((0, steps)))
    c = constants
    new_state = np.ascontiguousarray(state, dtype=float).copy()
    air = np.empty((n, steps))
    power = np.empty((n, steps))
    _run_day(new_state, history, air, power,
             per_instance("t_out"), per_instance("t_sky"), per_instance("pressure"),
             per_instance("humidity"), per_instance("wind"),
             np.ascontiguousarray(inputs["source"], dtype=float),
             np.ascontiguousarray(inputs["boundary"], dtype=float),
             np.ascontiguousarray(internal, dtype=float), inputs["internal"] is not None,
             np.ascontiguousarray(inputs["heat"], dtype=float),
             np.ascontiguousarray(inputs["cool"], dtype=float), exchange_schedules,
             c.faces, c.dz, c.gradient, c.curve, c.curve_bounds, c.face_area, c.radiant_area,
             c.window, c.gap_width, c.pane_out, c.pane_in, c.exterior_nodes, c.exterior,
             c.exterior_view, c.outside_wind, c.outside_natural, c.ventilation, c.volume,
             c.zone_wind_factor, c.exchange, c.exchange_outdoor, c.standard_density, c.c_dt,
             c.static_diagonal, c.chain_nodes, c.chain_start, c.chain_links, c.gap_chain,
             c.gap_position, c.air_coefficient, c.air_history, c.dt)
    return new_state, air, power


@njit(cache=True, error_model="numpy")
def _run_day(state, history, air_out, power_out, t_out_all, t_sky_all, pressure_all,
             humidity_all, wind_all, source, boundary, internal, has_internal, heat, cool,
             exchange_schedules, faces, dz, gradient, curve, curve_bounds, face_area,
             radiant_area, window, gap_width, pane_out, pane_in, exterior_nodes, exterior,
             exterior_view, outside_wind, outside_natural, ventilation, volume,
             zone_wind_factor, exchange, exchange_outdoor, standard_density, c_dt,
             static_diagonal, chain_nodes, chain_start, chain_links, gap_chain, gap_position,
             air_coefficient, air_history, dt):  # pragma: no cover - compiled
    n, size = state.shape
    steps = heat.shape[0]
    faces_count = faces.shape[0]
    chains, length = chain_nodes.shape
    air_node, star_node = 0, 1
    diagonal = np.empty(size)
    rhs = np.empty(size)
    d = np.empty((chains, length))
    e = np.empty((chains, length))
    links = np.empty((chains, max(length - 1, 1)))
    free = np.empty(size)
    unit = np.empty(size)
    g_conv = np.empty(faces_count)
    g_rad = np.empty(faces_count)
    t_free_chain = np.empty(length)
    t_unit_chain = np.empty(length)
    for i in range(n):
        for k in range(steps):
            t_out = t_out_all[i, k]
            t_sky = t_sky_all[i, k]
            pressure = pressure_all[i, k]
            humidity = humidity_all[i, k]
            wind = wind_all[i, k]
            t_air = state[i, air_node]
            grad = gradient[i]
            cp = 1.00484e3 + 1.85895e3 * humidity
            for node in range(size):
                diagonal[node] = c_dt[i, node] + static_diagonal[i, node]
                rhs[node] = (c_dt[i, node] * state[i, node] + source[i, k, node]
                             + boundary[i, k, node])
                if has_internal:
                    rhs[node] += internal[i, k, node]
            # inside faces: convection at the stratified adjacent air, long-wave to the star
            t_star = state[i, star_node] + KELVIN
            linear = 4 * SIGMA * t_star ** 3
            for j in range(faces_count):
                node = faces[j]
                adjacent = t_air + grad * dz[j]
                x = abs(state[i, node] - adjacent)
                h = _curve(curve[i, j, 0], curve[i, j, 1], curve[i, j, 2],
                           curve_bounds[j, 0], curve_bounds[j, 1], x)
                g_conv[j] = max(h, H_MIN) * face_area[i, j]
                g_rad[j] = linear * radiant_area[i, j]
                offset = g_conv[j] * grad * dz[j]
                rhs[node] += offset
                rhs[air_node] -= offset
                diagonal[node] += g_conv[j] + g_rad[j]
                diagonal[air_node] += g_conv[j]
                diagonal[star_node] += g_rad[j]
            gap = _gap_conductance(state[i, pane_out], state[i, pane_in], window[i, 0],
                                   window[i, 1], gap_width, pressure)
            g_gap = window[i, 3] / (1 / gap + window[i, 2])
            diagonal[pane_out] += g_gap
            diagonal[pane_in] += g_gap
            # outdoor air on the air node: the constant flow and the scheduled exchanges
            density = pressure / (287.042 * (t_out + KELVIN) * (1 + 1.607858 * humidity))
            vent = ventilation[i] * density * cp
            local_wind = wind * zone_wind_factor
            delta_t = abs(t_air - t_out)
            for x_index in range(exchange.shape[0]):
                flow = exchange[x_index, i, 0] * exchange_schedules[x_index, k] * (
                    exchange[x_index, i, 1] + exchange[x_index, i, 2] * delta_t
                    + exchange[x_index, i, 3] * local_wind
                    + exchange[x_index, i, 4] * local_wind * local_wind)
                rho = density if exchange_outdoor[x_index] else standard_density
                vent += max(flow, 0.0) * rho * cp
            diagonal[air_node] += vent
            rhs[air_node] += vent * t_out
            # outside faces: convection and long-wave to sky, ground and air
            for x_index in range(exterior_nodes.shape[0]):
                node = exterior_nodes[x_index]
                t_s = state[i, node]
                h_conv = max(_curve(outside_wind[i, x_index, 0], outside_wind[i, x_index, 1],
                                    outside_wind[i, x_index, 2], outside_wind[i, x_index, 3],
                                    outside_wind[i, x_index, 4], wind * exterior[i, x_index, 2])
                             + _curve(outside_natural[i, x_index, 0],
                                      outside_natural[i, x_index, 1],
                                      outside_natural[i, x_index, 2],
                                      outside_natural[i, x_index, 3],
                                      outside_natural[i, x_index, 4], abs(t_s - t_out)),
                             H_MIN)
                f_sky, f_ground, beta = (exterior_view[x_index, 0], exterior_view[x_index, 1],
                                         exterior_view[x_index, 2])
                eps = exterior[i, x_index, 1]
                ks, ka, ky = t_s + KELVIN, t_out + KELVIN, t_sky + KELVIN
                h_air = eps * SIGMA * (ks * ks + ka * ka) * (ks + ka) * (f_sky * (1 - beta)
                                                                         + f_ground)
                h_sky = eps * SIGMA * (ks * ks + ky * ky) * (ks + ky) * f_sky * beta
                area = exterior[i, x_index, 0]
                g_a, g_s = (h_conv + h_air) * area, h_sky * area
                diagonal[node] += g_a + g_s
                rhs[node] += g_a * t_out + g_s * t_sky
            # the air node's third-order backward difference (EnergyPlus's default)
            c_air = volume * (pressure / (287.042 * (t_air + KELVIN) * (1 + 1.607858 * humidity))
                              ) * cp
            diagonal[air_node] += c_air / dt * air_coefficient
            past = (air_history[0] * history[i, 0] + air_history[1] * history[i, 1]
                    + air_history[2] * history[i, 2])
            rhs[air_node] += c_air / dt * past
            # eliminate every chain onto the two hubs (forward sweep from its outside end)
            for ch in range(chains):
                for p in range(length):
                    node = chain_nodes[ch, p]
                    if p < chain_start[ch]:
                        d[ch, p] = 1.0
                        e[ch, p] = 0.0
                    else:
                        d[ch, p] = diagonal[node]
                        e[ch, p] = rhs[node]
                for p in range(length - 1):
                    links[ch, p] = chain_links[i, ch, p]
            if gap_chain >= 0:
                links[gap_chain, gap_position] = g_gap
            m_aa = diagonal[air_node]
            m_ss = diagonal[star_node]
            m_as = 0.0
            r_a = rhs[air_node]
            r_s = rhs[star_node]
            for ch in range(chains):
                for p in range(chain_start[ch] + 1, length):
                    f = links[ch, p - 1] / d[ch, p - 1]
                    d[ch, p] -= f * links[ch, p - 1]
                    e[ch, p] += f * e[ch, p - 1]
                inner_d = d[ch, length - 1]
                inner_e = e[ch, length - 1]
                m_aa -= g_conv[ch] * g_conv[ch] / inner_d
                m_ss -= g_rad[ch] * g_rad[ch] / inner_d
                m_as += g_conv[ch] * g_rad[ch] / inner_d
                r_a += g_conv[ch] * inner_e / inner_d
                r_s += g_rad[ch] * inner_e / inner_d
            det = m_aa * m_ss - m_as * m_as
            # the free state, and the response to 1 W on the air node
            free_a = (m_ss * r_a + m_as * r_s) / det
            free_s = (m_as * r_a + m_aa * r_s) / det
            unit_a = m_ss / det
            unit_s = m_as / det
            free[air_node], free[star_node] = free_a, free_s
            unit[air_node], unit[star_node] = unit_a, unit_s
            for ch in range(chains):
                last = length - 1
                inner_d = d[ch, last]
                t_free_chain[last] = (e[ch, last] + g_conv[ch] * free_a
                                      + g_rad[ch] * free_s) / inner_d
                t_unit_chain[last] = (g_conv[ch] * unit_a + g_rad[ch] * unit_s) / inner_d
                for p in range(last - 1, chain_start[ch] - 1, -1):
                    t_free_chain[p] = (e[ch, p] + links[ch, p] * t_free_chain[p + 1]) / d[ch, p]
                    t_unit_chain[p] = links[ch, p] * t_unit_chain[p + 1] / d[ch, p]
                for p in range(chain_start[ch], length):
                    free[chain_nodes[ch, p]] = t_free_chain[p]
                    unit[chain_nodes[ch, p]] = t_unit_chain[p]
            # the ideal air system: the power that holds the air at its setpoint
            if free_a < heat[k]:
                q = (heat[k] - free_a) / unit_a
            elif free_a > cool[k]:
                q = (cool[k] - free_a) / unit_a
            else:
                q = 0.0
            for node in range(size):
                state[i, node] = free[node] + q * unit[node]
            air_out[i, k] = state[i, air_node]
            power_out[i, k] = q
            history[i, 2] = history[i, 1]
            history[i, 1] = history[i, 0]
            history[i, 0] = state[i, air_node]
