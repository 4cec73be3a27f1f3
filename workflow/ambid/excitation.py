"""Adaptive-amplitude stepped-sine identification (thesis ch. 4.2), batched.

One axis at a time is excited at the controller output, ``E_u = A sin(2 pi f t)``
(eq. 4.2).  A step settles, then records every channel over an integer number
of periods; if the excited axis' peak response lies below ``r_min`` the
amplitude grows by 20 %, above ``r_max`` it shrinks by 20 %, and the step
repeats from where the machine is, as the thesis' PLC did.  A step is
accepted when the response is in the band or the amplitude has reached
``A_min`` / ``A_max``; beyond the thesis, ``A_max`` of an axis is at most a
fraction of its bias current (`amplitude_limits`).

Every frequency step of every axis is an independent experiment on the same
machine at rest, so all of them run as one batch through the rig, in lockstep
cycle by cycle; steps that are accepted leave the batch.  The Fourier
coefficient of each channel at the excitation frequency (its phase referred to
the start of the excitation) and a noise estimate from the two neighbouring
DFT lines of the same window form the identification log.
"""

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError, settings_from_mapping
from .loop import axial_transfer_functions, transfer_functions
from .machine import ALL_AXES, AXIAL_AXIS, RADIAL_AXES

__all__ = ["SteppedSineSettings", "settings_from_config", "adapt_amplitude", "amplitude_limits", "measurement_windows",
           "initial_amplitudes", "StepPlan", "run_stepped_sine"]


@dataclass(frozen=True)
class SteppedSineSettings:
    """Settings of the identification run (thesis ch. 4.2 defaults).

    Attributes
    ----------
    response_min_m, response_max_m : float
        Band of the excited axis' peak response (r_min = 20 um, r_max = 50 um).
    amplitude_min_a, amplitude_max_a : float
        Excitation amplitude limits (A_min = 50 mA, A_max = 3 A).
    growth, shrink : float
        Relative amplitude change when the response is below / above the band (0.2).
    initial_amplitude_a : float or None
        Amplitude each step starts with; None predicts it from the nominal model's
        dynamic compliance so that the response lands mid-band.
    settle_periods, settle_min_s, settle_max_s : float
        Settling before each measurement: this many periods, clipped to [min, max] seconds.
    measure_periods, measure_min_s : float
        Measurement window: at least this many whole periods (>= 2) and this many seconds.
    max_attempts : int
        A step still outside the band after this many measurements is accepted as is (logged).
    axes : tuple of str
        Excitation order (thesis: DX, DY, NX, NY, then Z).
    repeat_ratio : float or None
        Beyond the thesis: every ``repeat_every``-th step, once accepted, is measured
        again at ``repeat_ratio`` times its amplitude (log level 1), so the FRF stage
        can measure the amplitude-dependent error of the force law (`ambid.floor`).
        None: no repeats (the thesis' procedure).
    repeat_every : int
        Step stride of the repeats (1: every step; steps 0, k, 2k, ... of each axis).
    max_bias_fraction : float or None
        Beyond the thesis: an axis' excitation amplitude is at most this fraction of its bias current
        (`amplitude_limits`); None: ``amplitude_max_a`` alone.
    """

    response_min_m: float = 20e-6
    response_max_m: float = 50e-6
    amplitude_min_a: float = 0.05
    amplitude_max_a: float = 3.0
    growth: float = 0.2
    shrink: float = 0.2
    initial_amplitude_a: float | None = None
    settle_periods: float = 2.0
    settle_min_s: float = 0.3
    settle_max_s: float = 1.0
    measure_periods: int = 2
    measure_min_s: float = 0.1
    max_attempts: int = 30
    axes: tuple = ALL_AXES
    repeat_ratio: float | None = None
    repeat_every: int = 1
    max_bias_fraction: float | None = None

    def __post_init__(self):
        checks = [
            ("response_max_m", self.response_min_m > 0 and self.response_max_m > self.response_min_m, "must exceed response_min_m > 0"),
            ("amplitude_max_a", self.amplitude_min_a > 0 and self.amplitude_max_a >= self.amplitude_min_a, "must be >= amplitude_min_a > 0"),
            ("growth", 0 < self.growth, "must be > 0"),
            ("shrink", 0 < self.shrink < 1, "must lie in (0, 1)"),
            ("measure_periods", self.measure_periods >= 2 and float(self.measure_periods).is_integer(), "must be a whole number >= 2 (the noise lines sit beside it)"),
            ("settle_max_s", 0 <= self.settle_min_s <= self.settle_max_s, "must be >= settle_min_s >= 0"),
            ("max_attempts", self.max_attempts >= 1, "must be >= 1"),
            ("repeat_ratio", self.repeat_ratio is None or 0 < self.repeat_ratio < 1, "must lie in (0, 1) (or null: no repeats)"),
            ("repeat_every", float(self.repeat_every).is_integer() and self.repeat_every >= 1, "must be a whole number >= 1"),
            ("max_bias_fraction", self.max_bias_fraction is None or 0 < self.max_bias_fraction <= 1,
             "must lie in (0, 1] (or null: amplitude_max_a alone)"),
        ]
        for key, ok, message in checks:
            if not ok:
                raise ConfigError(f"identification.{key}", message)
        bad = [a for a in self.axes if a not in ALL_AXES]
        if bad or len(set(self.axes)) != len(self.axes):
            raise ConfigError("identification.axes", f"must be distinct axes of {list(ALL_AXES)}, got {list(self.axes)}")
        if self.initial_amplitude_a is not None and not self.amplitude_min_a <= self.initial_amplitude_a <= self.amplitude_max_a:
            raise ConfigError("identification.initial_amplitude_a", "must lie between amplitude_min_a and amplitude_max_a")


def settings_from_config(config):
    """`SteppedSineSettings` from the ``identification:`` mapping (unknown keys name themselves)."""
    return settings_from_mapping(SteppedSineSettings, config, "identification")


def adapt_amplitude(amplitude_a, peak_response_m, settings, amplitude_max_a=None):
    """One amplitude adaptation of thesis ch. 4.2, vectorized.

    ``amplitude_max_a`` (per step, `amplitude_limits`) replaces ``settings.amplitude_max_a`` where given.

    Returns
    -------
    new_amplitude_a : array
        The amplitude of the next attempt (unchanged where accepted).
    accepted : array of bool
        Response in ``[r_min, r_max]``, or below the band at ``A_max``, or above it at ``A_min``.
    """
    amplitude = np.asarray(amplitude_a, dtype=float)
    peak = np.asarray(peak_response_m, dtype=float)
    low, high = peak < settings.response_min_m, peak > settings.response_max_m
    limit = settings.amplitude_max_a if amplitude_max_a is None else np.asarray(amplitude_max_a, dtype=float)
    at_max = amplitude >= limit * (1 - 1e-12)
    at_min = amplitude <= settings.amplitude_min_a * (1 + 1e-12)
    accepted = (~low & ~high) | (low & at_max) | (high & at_min)
    grown = np.minimum(amplitude * (1 + settings.growth), limit)
    shrunk = np.maximum(amplitude * (1 - settings.shrink), settings.amplitude_min_a)
    new = np.where(accepted, amplitude, np.where(low, grown, shrunk))
    return new, accepted


def measurement_windows(frequency_hz, sample_time_s, settings):
    """Settling and measurement windows of each step, and the exact excitation frequency.

    The measurement window holds a whole number P of periods in a whole number N
    of samples, so the excitation frequency is ``P / (N T)``: the grid frequency
    moved by at most half a sample per window (< 0.03 % here).  DC (bias
    currents) and the harmonics are then orthogonal to the lines P - 1, P, P + 1.

    Returns
    -------
    settle_samples, measure_samples, periods : int arrays
    exact_frequency_hz : array
    """
    f = np.asarray(frequency_hz, dtype=float)
    periods = np.maximum(settings.measure_periods, np.ceil(settings.measure_min_s * f)).astype(int)
    measure = np.round(periods / (f * sample_time_s)).astype(int)
    settle_s = np.clip(settings.settle_periods / f, settings.settle_min_s, settings.settle_max_s)
    settle = np.ceil(settle_s / sample_time_s).astype(int)
    return settle, measure, periods, periods / (measure * sample_time_s)


def amplitude_limits(machine, settings, bias_fraction=None):
    """The largest excitation amplitude of each axis (`ALL_AXES` order) [A]: ``amplitude_max_a``, and at most
    ``bias_fraction`` (default ``settings.max_bias_fraction``) of the axis' bias current on the drawing.

    Beyond the thesis.  The force law (eq. 3.6) is quadratic in each coil's current ``i_b +- i``: the
    describing function a sine of amplitude ``A`` measures departs from the linearized plant by a series in
    ``(A / i_b)^2``, whose first term the repeated steps measure and remove (`ambid.amplitude`), and at
    ``A`` near ``i_b`` one coil's current reaches zero and clips.  On demo20 (bias 3 A) at the thesis' 3 A,
    a noise-free rig's FRF at zero amplitude kept 0.07-0.24 % of error above 700 Hz, 10 to 110 times what the
    repeats state; at 1.5 A it is within them (median 0.5, largest 1.7 of its standard deviation).
    """
    fraction = settings.max_bias_fraction if bias_fraction is None else bias_fraction
    limit = np.full(len(ALL_AXES), float(settings.amplitude_max_a))
    if fraction is None:
        return limit
    return np.minimum(limit, fraction * machine.bias_currents_a)


def initial_amplitudes(plant, axis, frequency_hz, settings):
    """Start amplitude per step: mid-band response predicted by the nominal model's compliance.

    Uses the dynamic compliance E_u -> V2 (thesis Table 4.1) of the engineer's
    model, not the rig's truth; the adaptation corrects what the model gets wrong.
    Within the axis' `amplitude_limits`.
    """
    limit = amplitude_limits(plant.machine, settings)[ALL_AXES.index(axis)]
    if settings.initial_amplitude_a is not None:
        return np.full(len(frequency_hz), min(settings.initial_amplitude_a, limit))
    if axis == AXIAL_AXIS:
        compliance = np.abs(axial_transfer_functions(plant, frequency_hz)["dynamic_compliance"][:, 0, 0])
    else:
        k = RADIAL_AXES.index(axis)
        compliance = np.abs(transfer_functions(plant, frequency_hz)["dynamic_compliance"][:, k, k])
    target = 0.5 * (settings.response_min_m + settings.response_max_m)
    return np.clip(target / compliance, min(settings.amplitude_min_a, limit), limit)


@dataclass(frozen=True)
class StepPlan:
    """The frequency steps to run: parallel arrays, one entry per step."""

    axis: np.ndarray  # axis names
    step: np.ndarray  # index within the axis' grid
    frequency_hz: np.ndarray  # grid frequency
    initial_amplitude_a: np.ndarray
    amplitude_max_a: np.ndarray = None  # per step (`amplitude_limits`); None: the settings' ``amplitude_max_a``

    @classmethod
    def for_machine(cls, plant, settings):
        """The thesis plan: each axis of ``settings.axes`` over its grid (radial or axial).

        ``plant`` is the engineer's nominal model (start amplitudes only).
        """
        axes, steps, frequencies, amplitudes = [], [], [], []
        for axis in settings.axes:
            grid = plant.machine.axial_grid if axis == AXIAL_AXIS else plant.machine.radial_grid
            f = grid.frequency_hz
            axes += [axis] * f.size
            steps.append(np.arange(f.size))
            frequencies.append(f)
            amplitudes.append(initial_amplitudes(plant, axis, f, settings))
        axes = np.array(axes)
        limits = amplitude_limits(plant.machine, settings)[[ALL_AXES.index(a) for a in axes]]
        return cls(axes, np.concatenate(steps), np.concatenate(frequencies), np.concatenate(amplitudes), limits)


def run_stepped_sine(rig_model, plan, settings, seed=0, noise=True, progress=None, compact_every=64):
    """Run all planned steps through the rig in one batch.

    Parameters
    ----------
    rig_model : ambid.rig.RigModel
    plan : StepPlan
    settings : SteppedSineSettings
    seed : int
        Seed of the measurement noise.
    noise : bool
        False runs noise-free (tests).
    progress : callable, optional
        Called as ``progress(accepted_per_axis: dict, simulated_s: float)`` whenever steps are accepted.
    compact_every : int
        Cycles between removals of accepted steps from the batch.

    Returns
    -------
    records : list of dict
        One per step, the step records of `ambid.logs.identification_frame`
        (``excited_axis``, ``step``, ``frequency_hz`` (exact), ``amplitude_a``,
        ``attempts``, ``coefficients`` (20,), ``noise_std`` (20,), ``level`` 0), plus
        ``peak_response_m`` (peak of the excited axis' V2 about its mean over the
        window) and ``in_band``; then one record with ``level`` 1 per repeated step
        (``settings.repeat_ratio``), measured right after its step at the lower amplitude.
    stats : dict
        ``cycles`` (lockstep controller cycles), ``simulated_s`` (their time),
        ``experiment_s`` (the time the steps would take one after another, as on
        a real machine), ``member_cycles`` (cycles simulated summed over steps).
    """
    t = rig_model.sample_time_s
    n_steps = len(plan.step)
    settle, measure, periods, exact = measurement_windows(plan.frequency_hz, t, settings)
    axis_index = np.array([ALL_AXES.index(a) for a in plan.axis])
    offsets = np.concatenate([[0], np.cumsum(measure)])
    recordings = np.empty((20, offsets[-1]))  # the measurement windows, one segment per step
    rng = np.random.default_rng(seed) if noise else None

    amplitude = plan.initial_amplitude_a.astype(float).copy()
    attempts = np.ones(n_steps, dtype=int)
    elapsed = np.zeros(n_steps, dtype=int)  # cycles since the step's excitation started (kept here at compaction)
    state = rig_model.initial_state(n_steps)
    omega_t = 2 * np.pi * exact * t
    records = [None] * n_steps
    repeats = [None] * n_steps
    repeating = np.zeros(n_steps, dtype=bool)  # measuring the level-1 repeat of an accepted step
    repeat_planned = (settings.repeat_ratio is not None) & (plan.step % int(settings.repeat_every) == 0)
    finished = np.zeros(n_steps, dtype=bool)
    accepted_count = {a: 0 for a in settings.axes}
    cycles = member_cycles = 0
    # the batch, member by member (a step's id, its per-cycle constants and counters), taken anew at each compaction
    ids = np.arange(n_steps)
    batch = _Batch(ids, axis_index, omega_t, settle, measure, offsets, amplitude)
    while ids.size:
        excitation = np.zeros((len(ALL_AXES), ids.size))
        excitation[batch.axis, batch.member] = batch.amplitude * np.sin(batch.omega_t * batch.elapsed)
        channels = rig_model.step(state, excitation, rng)
        window = batch.counter - batch.settle
        measuring = (window >= 0) & (window < batch.measure) & batch.active
        if measuring.any():
            recordings[:, batch.offset[measuring] + window[measuring]] = channels[:, measuring]
        batch.counter += 1
        batch.elapsed += 1
        cycles += 1
        member_cycles += ids.size
        done = (batch.counter == batch.end) & batch.active
        if done.any():
            members = np.flatnonzero(done)
            elapsed[ids[members]] = batch.elapsed[members]
            for member in members[repeating[ids[members]]]:  # a repeat ends the step, without adaptation
                step = ids[member]
                repeats[step] = _evaluate(step, recordings[:, offsets[step] : offsets[step + 1]], periods[step], exact[step],
                                          elapsed[step] - measure[step], t, axis_index[step], amplitude[step], attempts[step],
                                          plan, level=1)
                repeats[step]["in_band"] = True  # measured at the lower level on purpose
                finished[step] = True
            members = members[~repeating[ids[members]]]
            adapting = ids[members]
            for step in adapting:
                records[step] = _evaluate(step, recordings[:, offsets[step] : offsets[step + 1]], periods[step], exact[step],
                                          elapsed[step] - measure[step], t, axis_index[step], amplitude[step], attempts[step], plan)
            peaks = np.array([records[s]["peak_response_m"] for s in adapting])
            new, accepted = adapt_amplitude(amplitude[adapting], peaks, settings,
                                            None if plan.amplitude_max_a is None else plan.amplitude_max_a[adapting])
            accepted |= attempts[adapting] >= settings.max_attempts
            for step, ok, value, peak in zip(adapting, accepted, new, peaks):
                records[step]["in_band"] = bool(settings.response_min_m <= peak <= settings.response_max_m)
                if ok and repeat_planned[step]:  # measure it again, at the lower level, from where the machine is
                    accepted_count[plan.axis[step]] += 1
                    repeating[step] = True
                    amplitude[step] = amplitude[step] * settings.repeat_ratio
                elif ok:
                    finished[step] = True
                    accepted_count[plan.axis[step]] += 1
                else:
                    amplitude[step] = value
                    attempts[step] += 1
            restarted = members[~finished[adapting]]  # a new attempt or the repeat: from the start of its settling
            batch.counter[restarted] = 0
            batch.amplitude[restarted] = amplitude[ids[restarted]]
            batch.active = ~finished[ids]
            if progress is not None and accepted.any():
                progress(dict(accepted_count), cycles * t)
        if cycles % compact_every == 0 and not batch.active.all():
            elapsed[ids] = batch.elapsed
            keep = batch.active
            ids = ids[keep]
            batch = batch.take(keep)
            state = state.take(keep)
    experiment_s = float(np.sum(elapsed) * t)
    records = records + [r for r in repeats if r is not None]
    return records, {"cycles": cycles, "simulated_s": cycles * t, "experiment_s": experiment_s, "member_cycles": member_cycles}


class _Batch:
    """The members of `run_stepped_sine`'s batch: per member, its step's constants (excited axis row, omega T,
    settling and measuring cycles, recording offset), its amplitude and its cycle counters, in batch order, so the
    per-cycle loop reads them without gathering through the step ids."""

    def __init__(self, ids, axis_index, omega_t, settle, measure, offsets, amplitude):
        self.axis, self.omega_t = axis_index[ids], omega_t[ids]
        self.settle, self.measure, self.offset = settle[ids], measure[ids], offsets[ids]
        self.end = self.settle + self.measure
        self.amplitude = amplitude[ids].copy()
        self.member = np.arange(ids.size)
        self.counter = np.zeros(ids.size, dtype=int)  # cycles into the current attempt
        self.elapsed = np.zeros(ids.size, dtype=int)  # cycles since the step's excitation started
        self.active = np.ones(ids.size, dtype=bool)  # not finished

    def take(self, keep):
        """The members kept at a compaction."""
        taken = object.__new__(_Batch)
        for name, value in vars(self).items():
            setattr(taken, name, value[keep])
        taken.member = np.arange(taken.axis.size)
        return taken


def _evaluate(step, segment, periods, frequency_hz, window_start_cycle, sample_time_s, axis, amplitude_a, attempts, plan, level=0):
    """Fourier coefficients at the excitation line and noise from the lines beside it."""
    n = segment.shape[1]
    k = np.arange(n)
    lines = np.exp(-2j * np.pi * np.outer(k, [periods - 1, periods, periods + 1]) / n)
    spectrum = (2.0 / n) * segment @ lines  # (20, 3)
    # refer the phase to the start of the excitation: x = A sin(w (k0 + k) T)
    coefficients = spectrum[:, 1] * np.exp(-2j * np.pi * frequency_hz * window_start_cycle * sample_time_s)
    noise_std = np.sqrt(0.5 * (np.abs(spectrum[:, 0]) ** 2 + np.abs(spectrum[:, 2]) ** 2))
    v2 = segment[5 + axis]
    return {
        "excited_axis": str(plan.axis[step]),
        "step": int(plan.step[step]),
        "frequency_hz": float(frequency_hz),
        "amplitude_a": float(amplitude_a),
        "attempts": int(attempts),
        "level": int(level),
        "coefficients": coefficients,
        "noise_std": noise_std,
        "peak_response_m": float(np.max(np.abs(v2 - np.mean(v2)))),
    }
