"""The RC network of the cell and its time stepping, vectorised over instances.

Nodes: the cell air (mean air temperature), a radiant star node for the
long-wave exchange between inside faces, finite-element nodes through each
opaque surface (outside face to inside face; for boundary surfaces the
outside face temperature is imposed, an internal mass's back face is
adiabatic), and the two glass panes (massless, as
in EnergyPlus's window heat balance).

Each step is implicit: ``(C/dt + K) T' = C/dt T + q`` (backward Euler for
the walls; the air node uses EnergyPlus's default third-order backward
difference) with the temperature-dependent conductances (inside convection
from the surface curves, outside convection, linearised long-wave exchange,
glazing gap) taken from the state at the start of the step. Every wall and
the glazing is a chain that touches only the air and star nodes, so each
step eliminates the chains onto those two hubs (a tridiagonal sweep per
chain, vectorised over instances), solves 2x2 and back-substitutes. The
ideal air system adds the power ``Q`` on the air node that brings the mean
air temperature to the heating (cooling) setpoint when it would otherwise
fall below (rise above) it: the system is linear in ``Q``, so the free state
and its response to ``Q`` come from the same elimination.

Room air stratification (ConstantGradient): the air next to a surface is
``T_mean + gradient * dz`` (``dz`` the surface centroid height above the
mid-height); convection uses that temperature, the ventilation air leaves at
the mean. EnergyPlus 25.2 holds the *mean* air temperature at the setpoint
(its thermostat offset only shifts the reported thermostat temperature) and
reports the ideal-loads power with the air leaving at the return air
temperature ``T_mean + return offset`` at the flow that delivers the load
from the supply-air temperature limit; :func:`reported_power` does the same.

Outdoor air enters the air node as a conductance ``rho c_p flow`` to the
outdoor temperature: the constant flow of the cell, plus each
:class:`~bpsflow.surrogate.cell.AirExchange` at its flow of the step, whose
``|T_zone - T_out|`` term takes the zone air temperature at the start of the
step (EnergyPlus's previous-step mean air temperature), keeping the step
linear. Internal gains (:class:`~bpsflow.surrogate.cell.InternalGain`) add
their convective part to the air node and their radiant part to the inside
faces, in proportion to area x thermal absorptance (EnergyPlus's distribution
of radiant internal gains, its ``TMULT x ITABSF``), the window's room-side
pane included.

Detailed quantities of the inside faces (temperature, adjacent air, the
convection coefficient and the terms of the face heat balance, seed eq. 15)
are recorded by a :class:`FaceProbe` only when asked for, so the ensemble
path does no extra work.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bpsflow.surrogate import kernel
from bpsflow.surrogate.cell import STANDARD_AIR_DENSITY, Cell, Curve
from bpsflow.surrogate.forcing import SIGMA, PeriodForcing, solar_inputs
from bpsflow.surrogate.kernel import H_MIN, KELVIN

#: Air-node time schemes: (coefficient of T, coefficients of T1, T2, T3).
AIR_SCHEMES = {1: (1.0, (1.0, 0.0, 0.0)), 3: (11 / 6, (3.0, -1.5, 1 / 3))}
#: Initial temperature of every node (EnergyPlus starts zones and surfaces at 23 °C).
T_INITIAL = 23.0


def air_density(pressure: np.ndarray, t_c: np.ndarray, humidity: np.ndarray) -> np.ndarray:
    """Moist air density (kg/m³)."""
    return pressure / (287.042 * (t_c + KELVIN) * (1 + 1.607858 * humidity))


def air_cp(humidity: np.ndarray) -> np.ndarray:
    """Moist air specific heat (J/kg K)."""
    return 1.00484e3 + 1.85895e3 * humidity


@dataclass
class Network:
    n: int                       # instances
    size: int                    # nodes
    capacity: np.ndarray         # (n, size) J/K (0 for massless nodes)
    static: np.ndarray           # (n, size*size) fixed conductances
    # Variable conductances between node pairs and to known temperatures.
    diag_nodes: list[int]
    inside: list[int]            # inside-face node of each opaque surface
    outside: list[int | None]    # outside-face node of outdoor surfaces
    boundary_node: list[int | None]   # first free node of boundary surfaces
    boundary_g: list[np.ndarray | None]  # its conductance to the imposed face (W/K)
    pane_out: int = 0
    pane_in: int = 0
    pairs: list[tuple[int, int]] = field(default_factory=list)
    off_columns: np.ndarray | None = None   # flat (i, j) and (j, i) of each pair
    off_pairs: np.ndarray | None = None     # the pair of each of those entries
    static_diagonal: np.ndarray | None = None  # (n, size) diagonal of ``static``
    #: Node chains outside -> inside (each opaque surface, then the glazing) and
    #: the conductances linking consecutive nodes (``None``: the glazing gap).
    chains: list[tuple[list[int], list[np.ndarray | None]]] = field(default_factory=list)

    AIR = 0
    STAR = 1


def build_network(cell: Cell) -> Network:
    n = cell.n
    nodes = 2
    capacity: list[np.ndarray] = [np.zeros(n), np.zeros(n)]
    static_pairs: list[tuple[int, int, np.ndarray]] = []
    inside, outside, boundary_node, boundary_g = [], [], [], []
    chains: list[tuple[list[int], list]] = []
    for surface in cell.opaque:
        # Element list outside -> inside.
        elements = []
        for layer in surface.layers:
            for _ in range(layer.elements):
                dx = layer.thickness / layer.elements
                elements.append((layer.conductivity / dx * surface.area,
                                 layer.density * layer.specific_heat * dx * surface.area))
        positions = len(elements) + 1
        ids: list[int | None] = []
        for p in range(positions):
            if p == 0 and not surface.outdoor and not surface.adiabatic:
                ids.append(None)         # imposed outside face
                continue
            c = np.zeros(n)
            if p > 0:
                c = c + elements[p - 1][1] / 2
            if p < len(elements):
                c = c + elements[p][1] / 2
            capacity.append(c)
            ids.append(nodes)
            nodes += 1
        links = []
        for p, (g, _) in enumerate(elements):
            if ids[p] is not None:
                static_pairs.append((ids[p], ids[p + 1], g))
                links.append(g)
        chains.append(([i for i in ids if i is not None], links))
        inside.append(ids[-1])
        outside.append(ids[0] if surface.outdoor else None)
        imposed = not (surface.outdoor or surface.adiabatic)
        boundary_node.append(ids[1] if imposed else None)
        boundary_g.append(elements[0][0] if imposed else None)
    pane_out, pane_in = nodes, nodes + 1
    chains.append(([pane_out, pane_in], [None]))
    capacity += [np.zeros(n), np.zeros(n)]
    nodes += 2

    size = nodes
    static = np.zeros((n, size, size))
    for i, j, g in static_pairs:
        static[:, i, i] += g
        static[:, j, j] += g
        static[:, i, j] -= g
        static[:, j, i] -= g
    for node, g in zip(boundary_node, boundary_g):
        if node is not None:
            static[:, node, node] += g

    pairs = []
    for node in inside:
        pairs += [(node, Network.AIR), (node, Network.STAR)]
    pairs += [(pane_in, Network.AIR), (pane_in, Network.STAR), (pane_out, pane_in)]
    diag_nodes = [Network.AIR] + [o for o in outside if o is not None] + [pane_out]
    return Network(n=n, size=size, capacity=np.stack(capacity, axis=1),
                   static=static.reshape(n, -1), diag_nodes=diag_nodes,
                   inside=inside, outside=outside, boundary_node=boundary_node,
                   boundary_g=boundary_g, pane_out=pane_out, pane_in=pane_in, pairs=pairs,
                   off_columns=np.array([i * size + j for i, j in pairs]
                                        + [j * size + i for i, j in pairs]),
                   off_pairs=np.array(list(range(len(pairs))) * 2),
                   static_diagonal=static[:, np.arange(size), np.arange(size)].copy(),
                   chains=chains)


def _gap_conductance(t1: np.ndarray, t2: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                     width: float, pressure: np.ndarray) -> np.ndarray:
    """Air gap conductance (W/m²K): radiation plus ISO 15099 vertical-cavity convection."""
    k1, k2 = t1 + KELVIN, t2 + KELVIN
    radiation = SIGMA * (k1 * k1 + k2 * k2) * (k1 + k2) / (1 / e1 + 1 / e2 - 1)
    mean = 0.5 * (k1 + k2)
    conductivity = 2.873e-3 + 7.760e-5 * mean
    viscosity = 3.723e-6 + 4.94e-8 * mean
    cp = 1002.737 + 1.2324e-2 * mean
    density = pressure * 28.97e-3 / (8.314462 * mean)
    rayleigh = (density ** 2 * width ** 3 * 9.81 * cp * np.abs(k1 - k2)
                / (viscosity * conductivity * mean))
    nusselt = np.where(rayleigh > 1e4, 0.0, 1 + 1.7596678e-10 * rayleigh ** 2.2984755)
    nusselt = np.maximum(nusselt, np.where(rayleigh > 5e4, 0.0795 * rayleigh ** 0.31,
                                           0.028154 * rayleigh ** 0.4134))
    return radiation + np.maximum(nusselt, 1.0) * conductivity / width


#: Inside-face quantities a :class:`FaceProbe` can record (hour means).
FACE_TERMS = ("temperature", "adjacent_air", "convection_coefficient", "convection",
              "conduction", "radiation", "solar", "internal_gains")


@dataclass
class FaceProbe:
    """Hour means of inside-face quantities, for the faces and quantities asked for.

    Faces are numbered like the stepper's: the opaque surfaces of the cell in
    order, then the window's room-side pane. Heat flows are per unit area and
    count as gains to the face (EnergyPlus's signs), so that at every face

    ``convection + conduction + radiation + solar + internal_gains = 0``  (seed eq. 15)

    with ``convection = h (T_adjacent - T_face)`` (seed eq. 16), ``h`` the
    face's user curve at ``|T_adjacent - T_face|`` of the start of the step
    (floored at :data:`H_MIN`; seed eq. 17), ``radiation`` the net long-wave
    exchange with the other faces, ``solar`` the absorbed short-wave and
    ``conduction`` the heat reaching the face from within the wall (the flow
    from the next node less what the face node's share of the wall stores;
    for the window, the flow from the outer pane, and ``solar`` what the
    room-side pane absorbs) and ``internal_gains`` the radiant internal gains
    the face absorbs (zero without internal gains; seed eq. 15 has none).

    Parameters
    ----------
    wanted : dict
        Face index -> the :data:`FACE_TERMS` to record for it.
    hours : int
        Hours of the period.
    steps_per_hour : int
        Time steps per hour.

    Attributes
    ----------
    values : dict
        ``(face, term)`` -> hour means, ``(n, hours)``; °C, W/m²K or W/m².
    """

    wanted: dict[int, set[str]]
    hours: int
    steps_per_hour: int
    values: dict[tuple[int, str], np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = {t for terms in self.wanted.values() for t in terms} - set(FACE_TERMS)
        if unknown:
            raise ValueError(f"unknown face terms {sorted(unknown)}; expected {FACE_TERMS}")

    def record(self, stepper: _Stepper, old: np.ndarray, new: np.ndarray,
               g_pairs: np.ndarray, capacity: np.ndarray, inputs: dict, step: int,
               k: int) -> None:
        """Add one step's values (``step`` in the period, ``k`` in its day)."""
        hour = step // self.steps_per_hour
        weight = 1.0 / self.steps_per_hour
        for m, terms in self.wanted.items():
            for term in terms:
                total = self.values.get((m, term))
                if total is None:
                    total = self.values[(m, term)] = np.zeros((stepper.net.n, self.hours))
                total[:, hour] += weight * self._term(term, stepper, m, old, new, g_pairs,
                                                      capacity, inputs, k)

    def _term(self, term: str, stepper: _Stepper, m: int, old: np.ndarray, new: np.ndarray,
              g_pairs: np.ndarray, capacity: np.ndarray, inputs: dict, k: int) -> np.ndarray:
        """One quantity of face ``m`` at the end of a step, ``(n,)``."""
        net = stepper.net
        node = (net.inside + [net.pane_in])[m]
        area = stepper.opaque_areas[:, m]
        t_face = new[:, node]
        if term == "temperature":
            return t_face
        if term == "solar":
            return inputs["source"][:, k, node] / area
        if term == "internal_gains":
            internal = inputs["internal"]
            return np.zeros(stepper.net.n) if internal is None else internal[:, k, node] / area
        if term == "radiation":
            return g_pairs[:, 2 * m + 1] / area * (new[:, net.STAR] - t_face)
        if term == "conduction":
            return self._conduction(stepper, m, old, new, g_pairs, capacity, inputs, k) / area
        t_adjacent = new[:, net.AIR] + stepper.cell.gradient * stepper.dz[m]
        if term == "adjacent_air":
            return t_adjacent
        h = g_pairs[:, 2 * m] / area
        return h if term == "convection_coefficient" else h * (t_adjacent - t_face)

    @staticmethod
    def _conduction(stepper: _Stepper, m: int, old: np.ndarray, new: np.ndarray,
                    g_pairs: np.ndarray, capacity: np.ndarray, inputs: dict,
                    k: int) -> np.ndarray:
        """Heat (W) reaching inside face ``m`` from within its surface.

        For the window: across the gap and the panes from the outer pane.
        """
        net = stepper.net
        nodes, links = net.chains[m]
        face = nodes[-1]
        if links and links[-1] is None:
            inflow = g_pairs[:, -1] * (new[:, nodes[-2]] - new[:, face])
        elif len(nodes) > 1:
            inflow = links[-1] * (new[:, nodes[-2]] - new[:, face])
        else:
            # A one-node wall: the face links straight to the imposed outside face,
            # whose term the boundary input carries as g * T_imposed.
            inflow = inputs["boundary"][:, k, face] - net.boundary_g[m] * new[:, face]
        return inflow - capacity[:, face] / stepper.dt * (new[:, face] - old[:, face])


@dataclass
class Simulation:
    """Per-step results: end-of-step mean air temperature and ideal-loads power."""

    air: np.ndarray        # (n, steps) °C
    power: np.ndarray      # (n, steps) W, + heating, - cooling (delivered to the air)
    state: np.ndarray      # (n, size) final node temperatures
    warmup_days: int = 0
    energy: dict[str, np.ndarray] | None = None  # accounted energy per flow (J), when asked


def simulate(cell: Cell, network: Network, forcing: PeriodForcing, *,
             min_warmup_days: int = 6, max_warmup_days: int = 25,
             warmup_tolerance: float = 0.02, initial: np.ndarray | None = None,
             account: bool = False, air_order: int = 3, dense: bool = False,
             probe: FaceProbe | None = None, compiled: bool = True) -> Simulation:
    """Run a period: warm-up on its first day repeated, then every day in turn.

    ``probe`` (optional) records inside-face quantities over the period (not
    the warm-up). ``compiled`` steps with :mod:`bpsflow.surrogate.kernel`
    where it applies (no energy accounting, probe or dense solve); ``False``
    keeps the numpy step, the reference it is tested against.
    """
    n, size = network.n, network.size
    spd = forcing.steps_per_day
    dt = 3600.0 / forcing.steps_per_hour
    state = np.full((n, size), T_INITIAL) if initial is None else initial.copy()
    stepper = _Stepper(cell, network, forcing, dt, account, air_order, dense)
    stepper.compiled = compiled
    stepper.start(state)
    warmup = 0
    if max_warmup_days > 0:
        day0 = stepper.day_inputs(0)
        previous = state.copy()
        for warmup in range(1, max_warmup_days + 1):
            state, _, _ = stepper.run_day(state, day0, 0)
            change = np.max(np.abs(state - previous))
            previous = state.copy()
            if warmup >= min_warmup_days and change < warmup_tolerance:
                break
    stepper.reset_energy(state)
    stepper.probe = probe
    air = np.empty((n, forcing.steps))
    power = np.empty((n, forcing.steps))
    for day in range(forcing.days):
        inputs = stepper.day_inputs(day)
        state, air[:, day * spd:(day + 1) * spd], power[:, day * spd:(day + 1) * spd] = \
            stepper.run_day(state, inputs, day)
    return Simulation(air=air, power=power, state=state, warmup_days=warmup,
                      energy=stepper.energy_totals(state) if account else None)


class _Stepper:
    def __init__(self, cell: Cell, network: Network, forcing: PeriodForcing, dt: float,
                 account: bool, air_order: int = 3, dense: bool = False):
        self.cell, self.net, self.forcing = cell, network, forcing
        self.dt, self.account = dt, account
        n = network.n
        # (n, faces): an internal mass's area may differ between instances
        self.opaque_areas = np.stack([np.broadcast_to(np.asarray(a, dtype=float), (n,))
                                      for a in [s.area for s in cell.opaque] + [cell.window.area]],
                                     axis=1)
        self.area_total = self.opaque_areas.sum(axis=1)
        self.emissivity_in = [s.emissivity_in for s in cell.opaque] + [cell.window.emissivity_in]
        self.dz = np.array([s.dz for s in cell.opaque] + [cell.window.dz])
        curves = [s.inside_curve for s in cell.opaque] + [cell.window.inside_curve]
        # the inside faces' curves and emissivities as (n, faces) arrays: one numpy call per
        # step for every face, not one per face

        def faces_array(values: list) -> np.ndarray:
            return np.stack([np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in values],
                            axis=1)

        self.curve_c1 = faces_array([c.c1 for c in curves])
        self.curve_c2 = faces_array([c.c2 for c in curves])
        self.curve_c3 = faces_array([c.c3 for c in curves])
        self.curve_lower = np.array([c.x_min for c in curves], dtype=float)
        self.curve_upper = np.array([c.x_max for c in curves], dtype=float)
        self.radiant_area = faces_array(self.emissivity_in) * self.opaque_areas / (
            1 - self.opaque_areas / self.area_total[:, None])
        # each node's pairs: the diagonal gains every pair conductance of its node
        self.pair_incidence = np.zeros((len(network.pairs), network.size))
        for column, (i, j) in enumerate(network.pairs):
            self.pair_incidence[column, i] += 1.0
            self.pair_incidence[column, j] += 1.0
        self.rhs_air = np.zeros((n, network.size, 2))
        self.rhs_air[:, network.AIR, 1] = 1.0
        self.energy: dict[str, np.ndarray] = {}
        self.start_state: np.ndarray | None = None
        self.air_order = air_order
        self.history: Any = None     # the air temperatures of the last three steps
        self.dense = dense
        self.probe: FaceProbe | None = None
        self.compiled = True
        self._kernel: kernel.KernelConstants | None = None
        self.first_step = 0       # index in the period of the day's first step
        self._pad_chains()
        # per-step constants (the stepping loop is the surrogate's hot path)
        w = cell.window
        self.exterior: list[tuple] = [
            (node, s.area, s.emissivity_out, s.wind_factor, s.outside_wind, s.outside_natural,
             s.tilt) for node, s in zip(network.outside, cell.opaque) if node is not None]
        self.exterior.append((network.pane_out, w.area, w.emissivity_out, w.wind_factor,
                              w.outside_wind, w.outside_natural, w.tilt))
        self.capacity = network.capacity.copy()
        self.capacity[:, network.AIR] = 0.0
        self.c_dt = self.capacity / dt

    def _pad_chains(self) -> None:
        """The chains as one padded array, so each sweep step treats every chain at once.

        Shorter chains are padded at their outside end with neutral nodes
        (diagonal 1, no source, no link), which leave the sweep unchanged.
        """
        net = self.net
        length = max(len(nodes) for nodes, _ in net.chains)
        count = len(net.chains)
        self.chain_nodes = np.full((count, length), net.size)      # net.size: the padding
        self.chain_links = np.zeros((net.n, count, max(length - 1, 1)))
        self.gap_link: tuple[int, int] | None = None
        for c, (nodes, links) in enumerate(net.chains):
            offset = length - len(nodes)
            self.chain_nodes[c, offset:] = nodes
            for position, link in enumerate(links):
                if link is None:
                    self.gap_link = (c, offset + position)
                else:
                    self.chain_links[:, c, offset + position] = link
        real = self.chain_nodes < net.size
        self.chain_start = length - real.sum(axis=1)
        self.chain_real = np.nonzero(real)
        self.chain_real_nodes = self.chain_nodes[real]

    def start(self, state: np.ndarray) -> None:
        air = state[:, self.net.AIR].copy()
        self.history = (air, air, air)

    # Inputs of one day ------------------------------------------------
    def day_inputs(self, day: int) -> dict:
        f = self.forcing
        spd = f.steps_per_day
        steps = slice(day * spd, (day + 1) * spd)
        n, size = self.net.n, self.net.size
        solar = solar_inputs(self.cell, f, steps)
        source = np.zeros((n, spd, size))
        for i, node in enumerate(self.net.inside):
            source[:, :, node] += solar[f"in:{i}"]
        for i, node in enumerate(self.net.outside):
            if node is not None:
                source[:, :, node] += solar[f"out:{i}"]
        source[:, :, self.net.pane_out] += solar["pane_out"]
        source[:, :, self.net.pane_in] += solar["pane_in"]
        boundary = np.zeros((n, spd, size))
        for node, g, temps in zip(self.net.boundary_node, self.net.boundary_g, f.boundary):
            if node is not None:
                boundary[:, :, node] += g[:, None] * temps[:, steps]
        take = lambda a: np.broadcast_to(a[:, steps], (n, spd))  # noqa: E731
        return {"source": source, "boundary": boundary, "t_out": take(f.t_out),
                "wind": take(f.wind), "t_sky": take(f.t_sky), "pressure": take(f.pressure),
                "humidity": take(f.humidity), "heat": f.heating_setpoint[steps],
                "cool": f.cooling_setpoint[steps], "internal": self._internal_gains(steps),
                "exchange_schedules": [f.schedules[a.schedule.name.upper()][steps]
                                       for a in self.cell.air_exchanges]}

    def _internal_gains(self, steps: slice) -> np.ndarray | None:
        """Internal gains per node over ``steps``, W, ``(n, s, size)`` (``None``: none)."""
        gains = self.cell.internal_gains
        if not gains:
            return None
        net, n = self.net, self.net.n
        faces = net.inside + [net.pane_in]
        absorbing = self.opaque_areas * np.stack(self.emissivity_in, axis=1)  # (n, faces)
        share = absorbing / absorbing.sum(axis=1, keepdims=True)
        convective = radiant = 0.0
        for gain in gains:
            level = gain.design_w[:, None] * self.forcing.schedules[
                gain.schedule.name.upper()][steps][None, :]              # (n, s) W
            convective = convective + gain.fraction_convective[:, None] * level
            radiant = radiant + gain.fraction_radiant[:, None] * level
        # each node's share of the radiant part, the air's of the convective: (n, size)
        radiant_share = np.zeros((n, net.size))
        for m, face in enumerate(faces):
            radiant_share[:, face] += share[:, m]
        out = np.asarray(radiant)[:, :, None] * radiant_share[:, None, :]
        out[:, :, net.AIR] += convective
        return out

    def kernel_constants(self) -> kernel.KernelConstants:
        """This run's constants for :func:`bpsflow.surrogate.kernel.run_day` (built once)."""
        if self._kernel is not None:
            return self._kernel
        cell, net, n = self.cell, self.net, self.net.n

        def instances(value: object) -> np.ndarray:
            return np.broadcast_to(np.asarray(value, dtype=float), (n,))

        def curve_array(curve: Curve) -> np.ndarray:
            return np.stack([instances(curve.c1), instances(curve.c2), instances(curve.c3),
                             instances(curve.x_min), instances(curve.x_max)], axis=1)

        w = cell.window
        tilts = np.radians([tilt for *_, tilt in self.exterior])
        f_sky = (1 + np.cos(tilts)) / 2
        exchanges = cell.air_exchanges
        coefficient, history = AIR_SCHEMES[self.air_order]
        gap_chain, gap_position = self.gap_link if self.gap_link is not None else (-1, -1)
        contiguous = np.ascontiguousarray
        self._kernel = kernel.KernelConstants(
            faces=np.array(net.inside + [net.pane_in], dtype=np.int64),
            dz=contiguous(self.dz, dtype=float),
            gradient=contiguous(instances(cell.gradient)),
            curve=contiguous(np.stack([self.curve_c1, self.curve_c2, self.curve_c3], axis=2)),
            curve_bounds=contiguous(np.stack([self.curve_lower, self.curve_upper], axis=1)),
            face_area=contiguous(self.opaque_areas), radiant_area=contiguous(self.radiant_area),
            window=contiguous(np.stack([instances(w.emissivity_gap_out),
                                        instances(w.emissivity_gap_in),
                                        instances(w.pane_resistance), instances(w.area)], axis=1)),
            gap_width=float(w.gap_thickness), pane_out=net.pane_out, pane_in=net.pane_in,
            exterior_nodes=np.array([node for node, *_ in self.exterior], dtype=np.int64),
            exterior=contiguous(np.stack([np.stack([instances(area), instances(eps),
                                                    instances(factor)], axis=1)
                                          for _, area, eps, factor, *_ in self.exterior],
                                         axis=1)),
            exterior_view=contiguous(np.stack([f_sky, (1 - np.cos(tilts)) / 2, np.sqrt(f_sky)],
                                              axis=1)),
            outside_wind=contiguous(np.stack([curve_array(hf) for *_, hf, _, _ in self.exterior],
                                             axis=1)),
            outside_natural=contiguous(np.stack([curve_array(hn)
                                                 for *_, hn, _ in self.exterior], axis=1)),
            ventilation=contiguous(instances(cell.ventilation_m3s)),
            volume=float(cell.volume), zone_wind_factor=float(cell.zone_wind_factor),
            exchange=contiguous(np.stack([np.stack([instances(a.design_m3s), instances(a.constant),
                                                    instances(a.temperature),
                                                    instances(a.velocity),
                                                    instances(a.velocity_squared)], axis=1)
                                          for a in exchanges]) if exchanges
                                else np.zeros((0, n, 5))),
            exchange_outdoor=np.array([a.density_basis == "outdoor" for a in exchanges],
                                      dtype=np.bool_),
            standard_density=float(STANDARD_AIR_DENSITY),
            c_dt=contiguous(self.c_dt, dtype=float),
            static_diagonal=contiguous(net.static_diagonal, dtype=float),
            chain_nodes=contiguous(self.chain_nodes, dtype=np.int64),
            chain_start=contiguous(self.chain_start, dtype=np.int64),
            chain_links=contiguous(self.chain_links, dtype=float),
            gap_chain=int(gap_chain), gap_position=int(gap_position),
            air_coefficient=float(coefficient), air_history=np.array(history, dtype=float),
            dt=float(self.dt))
        return self._kernel

    # Stepping ---------------------------------------------------------
    def run_day(self, state: np.ndarray, inputs: dict, day: int):
        spd = inputs["heat"].shape[0]
        n = self.net.n
        self.first_step = day * spd
        if self.compiled and not (self.account or self.dense or self.probe is not None):
            history = np.ascontiguousarray(np.stack(self.history, axis=1), dtype=np.float64)
            state, air, power = kernel.run_day(self.kernel_constants(), state, history, inputs)
            self.history = (history[:, 0].copy(), history[:, 1].copy(), history[:, 2].copy())
            return state, air, power
        air = np.empty((n, spd))
        power = np.empty((n, spd))
        for k in range(spd):
            state, power[:, k] = self.step(state, inputs, k)
            air[:, k] = state[:, self.net.AIR]
        return state, air, power

    def step(self, state: np.ndarray, inputs: dict, k: int):
        cell, net = self.cell, self.net
        n, size = net.n, net.size
        t_out = inputs["t_out"][:, k]
        t_sky = inputs["t_sky"][:, k]
        pressure = inputs["pressure"][:, k]
        humidity = inputs["humidity"][:, k]
        t_air = state[:, net.AIR]
        gradient = cell.gradient

        # Inside convection and long-wave exchange of each inside face.
        faces = net.inside + [net.pane_in]
        t_face = state[:, faces]                                    # (n, m)
        adjacent = t_air[:, None] + gradient[:, None] * self.dz[None, :]
        t_star = state[:, net.STAR] + KELVIN
        linear = 4 * SIGMA * t_star ** 3
        x = np.minimum(np.maximum(np.abs(t_face - adjacent), self.curve_lower), self.curve_upper)
        h = np.maximum(self.curve_c1 + self.curve_c2 * x ** self.curve_c3, H_MIN)
        g_conv = h * self.opaque_areas
        offset = g_conv * gradient[:, None] * self.dz[None, :]
        strat = np.zeros((n, size))
        strat[:, faces] += offset
        strat[:, net.AIR] -= offset.sum(axis=1)
        # pairs: (face, air) and (face, star) of each face, then the glazing gap
        g_pairs = np.empty((n, 2 * len(faces) + 1))
        g_pairs[:, 0:-1:2] = g_conv
        g_pairs[:, 1:-1:2] = linear[:, None] * self.radiant_area
        w = cell.window
        t_po, t_pi = state[:, net.pane_out], state[:, net.pane_in]
        gap = _gap_conductance(t_po, t_pi, w.emissivity_gap_out, w.emissivity_gap_in,
                               w.gap_thickness, pressure)
        g_pairs[:, -1] = w.area / (1 / gap + w.pane_resistance)

        # Outside faces: convection plus long-wave to sky, ground (at the air
        # temperature) and air; the ventilation air on the air node.
        wind = inputs["wind"][:, k]
        g_known = []          # diag nodes order: air, outdoor faces, pane_out
        rhs = np.zeros((n, size))
        density = air_density(pressure, t_out, humidity)
        cp = air_cp(humidity)
        vent = cell.ventilation_m3s * density * cp
        if cell.air_exchanges:
            vent = vent + self._exchange_conductance(inputs, k, t_air, t_out, wind, density, cp)
        g_known.append(vent)
        rhs[:, net.AIR] += vent * t_out
        flows_out = []
        for node, area, eps, factor, hf, hn, tilt in self.exterior:
            t_s = state[:, node]
            h_conv = np.maximum(hf(wind * factor) + hn(np.abs(t_s - t_out)), H_MIN)
            cos_tilt = np.cos(np.radians(tilt))
            f_sky, f_ground = (1 + cos_tilt) / 2, (1 - cos_tilt) / 2
            beta = np.sqrt(f_sky)
            ks, ka, ky = t_s + KELVIN, t_out + KELVIN, t_sky + KELVIN
            h_air = eps * SIGMA * (ks * ks + ka * ka) * (ks + ka) * (f_sky * (1 - beta) + f_ground)
            h_sky = eps * SIGMA * (ks * ks + ky * ky) * (ks + ky) * f_sky * beta
            g_a, g_s = (h_conv + h_air) * area, h_sky * area
            g_known.append(g_a + g_s)
            rhs[:, node] += g_a * t_out + g_s * t_sky
            flows_out.append((node, g_a, g_s))

        c_air = cell.volume * air_density(pressure, t_air, humidity) * air_cp(humidity)
        capacity, c_dt = self.capacity, self.c_dt
        c_dt_state = c_dt * state

        diagonal = c_dt + net.static_diagonal + g_pairs @ self.pair_incidence
        for node, g in zip(net.diag_nodes, g_known):
            diagonal[:, node] += g
        rhs += c_dt_state + inputs["source"][:, k] + inputs["boundary"][:, k] + strat
        # Air: EnergyPlus's third-order backward difference (its default zone air
        # heat balance), dT/dt ~ (11/6 T - 3 T1 + 3/2 T2 - 1/3 T3) / dt.
        h1, h2, h3 = self.history
        coefficient, history = AIR_SCHEMES[self.air_order]
        diagonal[:, net.AIR] += c_air / self.dt * coefficient
        past = history[0] * h1 + history[1] * h2 + history[2] * h3
        rhs[:, net.AIR] += c_air / self.dt * past
        if inputs["internal"] is not None:
            rhs += inputs["internal"][:, k]
        if self.dense:
            free, unit = self._solve_dense(diagonal, rhs, g_pairs)
        else:
            free, unit = self._solve_chains(diagonal, rhs, g_pairs)
        t_free, gain = free[:, net.AIR], unit[:, net.AIR]
        heat_sp, cool_sp = inputs["heat"][k], inputs["cool"][k]
        q = np.where(t_free < heat_sp, (heat_sp - t_free) / gain,
                     np.where(t_free > cool_sp, (cool_sp - t_free) / gain, 0.0))
        new = free + q[:, None] * unit
        if self.account:
            stored_air = c_air * (coefficient * new[:, net.AIR] - past)
            self._account(state, new, capacity, stored_air, q, inputs, k, vent, t_out, flows_out)
        if self.probe is not None:
            self.probe.record(self, state, new, g_pairs, capacity, inputs, self.first_step + k, k)
        self.history = (new[:, net.AIR], h1, h2)
        return new, q

    def _exchange_conductance(self, inputs: dict, k: int, t_air: np.ndarray,
                              t_out: np.ndarray, wind: np.ndarray, density: np.ndarray,
                              cp: np.ndarray) -> np.ndarray:
        """Conductance (W/K, ``(n,)``) of the time-varying outdoor air flows of step ``k``.

        ``flow = design x schedule x (A + B |T_zone - T_out| + C V + D V^2)``,
        floored at 0 (EnergyPlus sets negative flows to 0), with ``T_zone`` the
        air temperature at the start of the step and ``V`` the local wind speed
        at the zone centroid.
        """
        cell = self.cell
        local_wind = wind * cell.zone_wind_factor
        delta_t = np.abs(t_air - t_out)
        total = np.zeros(self.net.n)
        for exchange, schedule in zip(cell.air_exchanges, inputs["exchange_schedules"]):
            flow = exchange.design_m3s * schedule[k] * (
                exchange.constant + exchange.temperature * delta_t
                + exchange.velocity * local_wind
                + exchange.velocity_squared * local_wind * local_wind)
            rho = density if exchange.density_basis == "outdoor" else STANDARD_AIR_DENSITY
            total = total + np.maximum(flow, 0.0) * rho * cp
        return total

    def _solve_dense(self, diagonal, rhs, g_pairs):
        """Free state and unit-power response by a dense solve (reference for tests)."""
        net = self.net
        n, size = net.n, net.size
        matrix = net.static.copy()
        matrix[:, ::size + 1] = 0.0
        matrix[:, net.off_columns] -= g_pairs[:, net.off_pairs]
        matrix[:, ::size + 1] = diagonal
        self.rhs_air[:, :, 0] = rhs
        solution = np.linalg.solve(matrix.reshape(n, size, size), self.rhs_air)
        return solution[..., 0], solution[..., 1]

    def _solve_chains(self, diagonal, rhs, g_pairs):
        """Free state and unit-power response by eliminating every chain onto the hubs.

        Each chain is tridiagonal and touches only the air and star nodes (by
        its inside node), so a forward sweep from its outside end leaves one
        equation in the two hub temperatures; the hubs solve as a 2x2 system
        and the chains back-substitute. Exact, and far cheaper than a dense
        solve per instance. The chains are swept together, padded to one
        length (:meth:`_pad_chains`), and the unit response is a second
        right-hand side of the same sweep.
        """
        net = self.net
        air, star = net.AIR, net.STAR
        n = net.n
        count, length = self.chain_nodes.shape
        d = np.concatenate([diagonal, np.ones((n, 1))], axis=1)[:, self.chain_nodes]
        e = np.concatenate([rhs, np.zeros((n, 1))], axis=1)[:, self.chain_nodes]
        links = self.chain_links
        if self.gap_link is not None:
            links = links.copy()
            links[:, self.gap_link[0], self.gap_link[1]] = g_pairs[:, -1]
        for p in range(1, length):
            f = links[:, :, p - 1] / d[:, :, p - 1]
            d[:, :, p] -= f * links[:, :, p - 1]
            e[:, :, p] += f * e[:, :, p - 1]
        g_a, g_s = g_pairs[:, 0:2 * count:2], g_pairs[:, 1:2 * count:2]   # (n, chains)
        inner_d, inner_e = d[:, :, -1], e[:, :, -1]
        m_aa = diagonal[:, air] - (g_a * g_a / inner_d).sum(axis=1)
        m_ss = diagonal[:, star] - (g_s * g_s / inner_d).sum(axis=1)
        m_as = (g_a * g_s / inner_d).sum(axis=1)
        det = m_aa * m_ss - m_as * m_as
        # right-hand sides (n, 2): the free state, and the response to 1 W on the air
        r_a = np.empty((n, 2))
        r_a[:, 0] = rhs[:, air] + (g_a * inner_e / inner_d).sum(axis=1)
        r_a[:, 1] = 1.0
        r_s = np.zeros((n, 2))
        r_s[:, 0] = rhs[:, star] + (g_s * inner_e / inner_d).sum(axis=1)
        t_a = (m_ss[:, None] * r_a + m_as[:, None] * r_s) / det[:, None]
        t_s = (m_as[:, None] * r_a + m_aa[:, None] * r_s) / det[:, None]
        sources = np.zeros((n, count, length, 2))
        sources[..., 0] = e
        t = np.empty((n, count, length, 2))
        t[:, :, -1] = (sources[:, :, -1] + g_a[:, :, None] * t_a[:, None, :]
                       + g_s[:, :, None] * t_s[:, None, :]) / inner_d[:, :, None]
        for p in range(length - 2, -1, -1):
            t[:, :, p] = (sources[:, :, p] + links[:, :, p, None] * t[:, :, p + 1]) \
                / d[:, :, p, None]
        solved = np.empty((n, net.size, 2))
        solved[:, air], solved[:, star] = t_a, t_s
        solved[:, self.chain_real_nodes] = t[:, self.chain_real[0], self.chain_real[1]]
        return solved[..., 0], solved[..., 1]

    # Energy accounting (tests) ----------------------------------------
    def reset_energy(self, state: np.ndarray) -> None:
        n = self.net.n
        self.energy = {name: np.zeros(n) for name in
                       ("hvac", "solar", "internal", "ventilation", "exterior", "boundary",
                        "stored")}
        self.start_state = state.copy()

    def _account(self, old, new, capacity, stored_air, q, inputs, k, vent, t_out, flows_out):
        if not self.energy:
            return
        e, dt, net = self.energy, self.dt, self.net
        e["hvac"] += q * dt
        e["solar"] += inputs["source"][:, k].sum(axis=1) * dt
        if inputs["internal"] is not None:
            e["internal"] += inputs["internal"][:, k].sum(axis=1) * dt
        e["ventilation"] += vent * (t_out - new[:, net.AIR]) * dt
        for node, g_a, g_s in flows_out:
            e["exterior"] += (g_a * (t_out - new[:, node])
                              + g_s * (inputs["t_sky"][:, k] - new[:, node])) * dt
        for node, g in zip(net.boundary_node, net.boundary_g):
            if node is not None:
                imposed = inputs["boundary"][:, k, node] / g
                e["boundary"] += g * (imposed - new[:, node]) * dt
        e["stored"] += (capacity * (new - old)).sum(axis=1) + stored_air

    def energy_totals(self, state: np.ndarray) -> dict[str, np.ndarray]:
        return dict(self.energy)


def reported_power(cell: Cell, power: np.ndarray, air: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(heating, cooling) power as EnergyPlus's ideal loads report them, W ≥ 0.

    The load ``Q`` is delivered with supply air at the heating (cooling)
    supply temperature limit, mass flow ``Q / (cp (T_supply - T_mean))``;
    the reported rate uses the air leaving at ``T_mean + return offset``.
    """
    offset = cell.return_offset[:, None]
    heating = np.clip(power, 0.0, None)
    cooling = np.clip(-power, 0.0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        heat_factor = (cell.heating_supply_c - air - offset) / (cell.heating_supply_c - air)
        cool_factor = (air + offset - cell.cooling_supply_c) / (air - cell.cooling_supply_c)
    heating = np.where(heating > 0, heating * np.nan_to_num(heat_factor, nan=1.0), 0.0)
    cooling = np.where(cooling > 0, cooling * np.nan_to_num(cool_factor, nan=1.0), 0.0)
    return np.clip(heating, 0.0, None), np.clip(cooling, 0.0, None)
