"""Characteristic signatures: can a plausible change of an existing parameter explain the residuals?

A parameter's characteristic signature is the model's response to a change
of that parameter, hour by hour (seed §1.1.1.1: calibration and
characteristic signatures, after Liu et al.; here computed by perturbation
runs rather than read from a catalogue). The residual left by the fitted
model is projected on each candidate's signature *after* removing what the
fitted parameters can already do (the span of the fit's Jacobian): the
projection coefficient is the change of the parameter that best explains
the residual, and its share of the residual variance says how much it
explains. A change is plausible when it stays within the parameter's
plausible range: its distribution's 1–99 % quantiles, or ± ``plausible_change``
(relative) around a fixed value.

One bad run never stops the step. The plausible range is first clipped to
what EnergyPlus accepts in the fields the parameter sets (the IDD's bounds
and a glazing's T + R < 1, with the other parameters at their values:
:func:`physical_range`), so a perturbation is clipped before it runs and the
signature is divided by the change actually made. A run that still fails is
retried once at half the change, then left out; each of these is a note.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bpsflow.config import BoundaryTarget, Config, Parameter
from bpsflow.diagnosis.fitting import Simulator
from bpsflow.distributions import Constant, Discrete, Empirical, Sampler


@dataclass
class Candidate:
    """A parameter that may be mis-valued, with its plausible range (its units)."""

    parameter: Parameter
    nominal: float
    lower: float
    upper: float
    #: the plausible half-width before :func:`physical_range` clipped ``lower``/``upper``
    half_width: float | None = None


@dataclass
class Signature:
    """The model's hourly response per unit change of one parameter."""

    candidate: Candidate
    response: np.ndarray          # (n,) output units per parameter unit


@dataclass
class Explanation:
    """What the best change of one parameter does to the residuals."""

    name: str
    change: float                 # parameter units
    value: float                  # nominal + change
    plausible: bool
    share: float                  # share of the residual variance it explains
    corrected: np.ndarray         # residual minus the explained part (calibration hours)


def candidate_parameters(parameters: list[Parameter], fitted: list[str],
                         plausible_change: float) -> list[Candidate]:
    """Existing parameters that are not fitted and have a numeric value to change.

    Boundary sequence samplers and discrete/empirical choices are left out (no
    continuous change to project on); a fixed value of 0 has no relative range.
    """
    out = []
    for p in parameters:
        if p.name in fitted or any(isinstance(t, BoundaryTarget) for t in p.targets):
            continue
        distribution = p.distribution
        if isinstance(distribution, (Sampler, Discrete, Empirical)):
            continue
        nominal = float(distribution.nominal)
        if isinstance(distribution, Constant):
            if p.mode == "additive" or nominal == 0.0:
                continue
            half = abs(nominal) * plausible_change
            lower, upper = nominal - half, nominal + half
        else:
            lower, upper = (float(v) for v in distribution.ppf(np.array([0.01, 0.99])))
        if upper > lower:
            out.append(Candidate(p, nominal, lower, upper))
    return out


def _refusal(config: Config, sample: dict[str, float], name: str, value: float,
             entries: list | None = None) -> str | None:
    """Why EnergyPlus would refuse ``sample`` with ``name = value`` (``None``: it accepts it)."""
    from bpsflow.errors import BpsflowError
    from bpsflow.simulation.target_bounds import check_sample_values

    row = pd.DataFrame([{**sample, name: value}], index=pd.Index([0], name="instance"))
    try:
        check_sample_values(config, row, "the perturbed value", entries)
    except BpsflowError as exc:
        reason = re.sub(r"; \d+ of \d+ instances alike", "", exc.message)
        return reason.split(") sets ", 1)[-1] if ") sets " in reason else reason
    return None


def physical_range(config: Config, sample: dict[str, float], name: str, lower: float,
                   upper: float, *, tolerance: float = 1e-9, margin: float = 1e-6
                   ) -> tuple[float, float, list[str]]:
    """``[lower, upper]`` clipped to the values of ``name`` EnergyPlus accepts at ``sample``.

    The fields a parameter sets move monotonically with it (absolute,
    additive or relative mode; :func:`bpsflow.simulation.targets.apply_mode`),
    so the accepted values around the sample's value form an interval; each
    end that EnergyPlus would refuse (:func:`bpsflow.simulation.target_bounds
    .check_sample_values`: the IDD's minimum/maximum, a glazing's T + R < 1)
    is moved, by bisection, to the last accepted value, then ``margin``
    (relative to the distance moved) back inside.

    Parameters
    ----------
    config : Config
    sample : dict
        Every parameter's value (the other parameters stay there).
    name : str
        The parameter whose range is clipped; ``sample[name]`` must be accepted.
    lower, upper : float
        The range to clip (the parameter's units).

    Returns
    -------
    lower, upper : float
        The clipped range (equal to the sample's value on a side with no room).
    notes : list of str
        One per clipped end: the value asked, the value kept and why.
    """
    from bpsflow.simulation.target_bounds import targeted_fields

    entries = [e for e in targeted_fields(config)
               if any(p.name == name for p in e.parameters)]
    if not entries:
        return lower, upper, []      # no IDF field: nothing EnergyPlus could refuse

    def refusal(value: float) -> str | None:
        return _refusal(config, sample, name, value, entries)

    centre = float(sample[name])
    if refusal(centre) is not None:
        return centre, centre, [f"{name}: its current value {centre:.6g} is already refused "
                                f"by EnergyPlus ({refusal(centre)})"]
    ends, notes = [], []
    for end in (lower, upper):
        if refusal(end) is None:
            ends.append(end)
            continue
        inside, outside = 0.0, 1.0     # fractions of the way from the centre to ``end``
        while outside - inside > tolerance:
            middle = 0.5 * (inside + outside)
            if refusal(centre + middle * (end - centre)) is None:
                inside = middle
            else:
                outside = middle
        # the limit that binds first (e.g. T + R < 1 before the IDD's T <= 1)
        reason = refusal(centre + outside * (end - centre))
        kept = centre + inside * (1.0 - margin) * (end - centre)
        ends.append(kept)
        notes.append(f"{name}: {end:.6g} clipped to {kept:.6g} ({end - centre:+.4g} -> "
                     f"{kept - centre:+.4g} from {centre:.6g}), the limit of what EnergyPlus "
                     f"accepts (beyond it, the run would set {reason})")
    return ends[0], ends[1], notes


def clip_to_physical(config: Config, sample: dict[str, float], candidates: list[Candidate],
                     notes: list[str] | None = None) -> list[Candidate]:
    """Candidates with their plausible range clipped by :func:`physical_range`.

    A candidate left with no room on either side is dropped; both are noted
    in ``notes``.
    """
    out = []
    every_clip: list[str] = []
    for c in candidates:
        name = c.parameter.name
        lower, upper, clipped = physical_range(config, {**sample, name: c.nominal}, name,
                                               c.lower, c.upper)
        every_clip += clipped
        if not upper > lower:
            if notes is not None:
                notes.append(f"parameter {name} left out of the signatures: no change of it "
                             f"within its plausible range is accepted by EnergyPlus")
            continue
        out.append(Candidate(c.parameter, c.nominal, lower, upper,
                             half_width=(c.upper - c.lower) / 2))
    if notes is not None and len(every_clip) > 2:
        # one line for many (a model's glazing and absorptances): the other notes stay visible
        notes.append(f"parameter signatures: {len(every_clip)} perturbations clipped to the "
                     f"limits EnergyPlus accepts: "
                     + "; ".join(clip.split(", the limit of what")[0] for clip in every_clip))
    elif notes is not None:
        notes.extend(f"parameter {clip}" for clip in every_clip)
    return out


def _step(c: Candidate, fraction: float) -> float:
    """``fraction`` of the plausible half-range, towards the side with more room, clipped."""
    half = c.half_width if c.half_width is not None else (c.upper - c.lower) / 2
    step = fraction * half
    room_up, room_down = c.upper - c.nominal, c.nominal - c.lower
    if room_up >= step:
        return step
    if room_down >= step:
        return -step
    return room_up if room_up >= room_down else -room_down


def signatures(simulate: Simulator, sample: dict[str, float], candidates: list[Candidate],
               prediction: np.ndarray, fraction: float = 0.2,
               notes: list[str] | None = None) -> list[Signature]:
    """Perturbation responses of each candidate (one batch of ``len(candidates)`` runs).

    Each candidate moves by ``fraction`` of its plausible half-range, towards
    the side with room, clipped to its range (see :func:`clip_to_physical`);
    the response is divided by the change actually made. ``prediction`` is
    the unperturbed model at ``sample``. A run that fails (a NaN row, the
    failure signal of :class:`~bpsflow.diagnosis.fitting.OutputSimulator`)
    is retried once at half its change in a second batch, then left out;
    clipped-to-nothing and left-out candidates are noted in ``notes``.
    """
    steps = {}
    for index, c in enumerate(candidates):
        step = _step(c, fraction)
        if step == 0.0:
            if notes is not None:
                notes.append(f"parameter {c.parameter.name} left out of the signatures: its "
                             f"change is clipped to zero")
            continue
        steps[index] = step
    found: dict[int, Signature] = {}
    errors: dict[int, str] = {}
    for attempt in range(2):
        todo = [i for i in steps if i not in found]
        if not todo:
            break
        rows = [{**sample, candidates[i].parameter.name: candidates[i].nominal + steps[i]}
                for i in todo]
        predicted = simulate(pd.DataFrame(rows, index=pd.RangeIndex(len(rows), name="instance")))
        failures = getattr(simulate, "failures", None) or {}
        for row, i in enumerate(todo):
            if np.isfinite(predicted[row]).all():
                found[i] = Signature(candidates[i], (predicted[row] - prediction) / steps[i])
                continue
            errors[i] = failures.get(row) or "non-finite output"
            if attempt == 0:
                steps[i] /= 2     # retried once, closer to the running value
    for i in steps:
        if i not in found and notes is not None:
            name = candidates[i].parameter.name
            notes.append(f"parameter {name} left out of the signatures: its run failed twice "
                         f"(change {2 * steps[i]:+.4g}, then {steps[i]:+.4g}): "
                         f"{_excerpt(errors.get(i, ''))}")
    return [found[i] for i in sorted(found)]


def _excerpt(error: str, size: int = 300) -> str:
    text = " ".join(str(error).split())
    return text if len(text) <= size else text[:size] + " ..."


def explain(residual: np.ndarray, fitted_jacobian: np.ndarray,
            found: list[Signature], calibration: np.ndarray,
            movable: np.ndarray | None = None) -> list[Explanation]:
    """Project the calibration-hour residual on each signature, net of the fitted span.

    ``movable`` (bool per fitted parameter) leaves out of the span the
    fitted parameters stuck at a bound of their range: they could not absorb
    more, so what lies along their direction is still to be explained.
    Returns the explanations sorted by explained share (largest first).
    """
    calibration = np.asarray(calibration, dtype=bool)
    r = np.asarray(residual, dtype=float)
    columns = fitted_jacobian[calibration]
    if movable is not None:
        columns = columns[:, np.asarray(movable, dtype=bool)]
    span = np.column_stack([np.ones(int(calibration.sum())), columns])
    projector = span @ np.linalg.pinv(span)
    r_free = r - projector @ r
    total = float(np.sum((r - r.mean()) ** 2))
    out = []
    for s in found:
        column = s.response[calibration]
        own = column - projector @ column
        norm = float(own @ own)
        if norm <= 1e-12 * max(float(column @ column), 1e-300):
            continue
        change = float(own @ r_free) / norm
        explained = change ** 2 * norm
        c = s.candidate
        value = c.nominal + change
        out.append(Explanation(name=c.parameter.name, change=change, value=value,
                               plausible=bool(c.lower <= value <= c.upper),
                               share=explained / total if total > 0 else 0.0,
                               corrected=r - change * own))
    return sorted(out, key=lambda e: -e.share)
