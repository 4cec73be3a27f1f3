"""Model against measurement: FRF errors per channel, frequency and band, weighted by the measurement uncertainty.

The channels compared are every one the identification logged
(`measured_channels`): the radial plant matrix (MIMO, or SISO diagonal when
only SISO runs exist), the axial plant and the coil-current responses
``I_<axis>`` (commanded -> measured coil current, the amplifier alone).

For every channel ``G_meas(f)`` with standard uncertainty ``sigma(f)`` (the
complex standard deviation of the ETFE's noise, ``E|n|^2 = sigma^2``, combined
with the systematic error the FRF stage measured from the data,
``sqrt(std^2 + systematic_std^2)``: the stepped sine's amplitude nonlinearity,
`ambid.floor`) and the model's ``G_model(f)`` (`model_response`: structural
plant with its effects times the digital loop's zero-order hold, as the
measurement sees it):

* ``magnitude_error_db = 20 log10 |G_model / G_meas|``
* ``phase_error_deg = angle(G_model / G_meas)`` in (-180, 180]
* ``normalized_error = |G_model - G_meas| / sigma``: about 1 where the model
  explains the data to within its noise.

The summary per channel and band is ``chi2 = mean(normalized_error^2)``
(1 at the noise floor), its excess ``max(chi2 - 1, 0)``, and the rms of the
magnitude and phase errors.  This is the "compare" step of the diagnosis loop.
"""

from dataclasses import replace
from typing import NamedTuple

import numpy as np
import pandas as pd
import scipy.linalg

from .effects import COIL_CURRENT_EFFECTS, EFFECTS, at_excitation_level, series_state_space
from .errors import AmbidError
from .floor import RESOLVED, band_labels, frequency_bands
from .frf import channel
from .loop import zero_order_hold
from .machine import ALL_AXES, AXIAL_AXIS, COIL_CURRENT_SAMPLING, RADIAL_AXES
from .findings import Finding
from .plant import Plant, zoh_discretize
from .sampled_loop import coupling_matrix

__all__ = ["CompareError", "measured_channels", "PointShares", "effective_shares", "input_coupling_slopes",
           "input_coupling", "at_input_coupling", "model_response", "model_channels",
           "channel_errors", "summarize", "current_channel", "channel_family", "truncation_error", "enough_modes",
           "with_enough_modes", "at_run_level",
           "for_run", "sampled_chain", "coil_current_sampling_fit", "with_coil_current_sampling"]


#: The coil-current sampling of a machine file that does not say, and of `with_coil_current_sampling` where the data
#: do not tell.
DEFAULT_SAMPLING = COIL_CURRENT_SAMPLING[0]
#: What each coil-current sampling convention means, as the findings say it.
SAMPLING_TOLD = {"start_of_cycle": "sampled at the start of the cycle, before its command acts",
                 "cycle_average": "averaged over the cycle of the command"}
#: chi2 by which one coil-current sampling convention must fit better than the other to be taken from the data.
SAMPLING_EVIDENCE = 10.0


class CompareError(AmbidError):
    """A comparison that cannot be made (no common channel, no usable uncertainty)."""


def current_channel(axis):
    """Name of the coil-current output of an axis in the comparison (``I_DX``)."""
    return f"I_{axis}"


def channel_family(output):
    """Family of a compared channel by its output: ``currents`` (``I_<axis>``), ``axial`` (``Z``) or ``positions``."""
    return "currents" if output.startswith("I_") else "axial" if output == AXIAL_AXIS else "positions"


def measured_channels(table, position_floor=0.0, current_floor=0.0):
    """Every logged channel of an FRF table, with the uncertainty the comparison uses.

    Parameters
    ----------
    table : pandas.DataFrame
        `ambid.frf.frf_table` of one run; its ``systematic_std`` (`ambid.floor`)
        is added in quadrature to the noise ``std``.
    position_floor, current_floor : float
        Relative systematic uncertainty of the position (plant) and coil-current
        channels for rows whose ``systematic_std`` is NaN or absent (a table made
        without `ambid.floor`, e.g. in a study); the FRF stage fills every row.

    Returns
    -------
    dict
        ``(output, input) -> (frequency_hz, values, std)``: the radial matrix
        (MIMO when logged, else the SISO diagonal), ``("Z", "Z")`` and
        ``("I_<axis>", axis)`` for the coil currents.
    """
    if position_floor < 0 or current_floor < 0:
        raise CompareError(f"relative floors must be >= 0, got {position_floor}, {current_floor}")
    out = {}
    for key, (estimator, output, input_axis) in _compared(table).items():
        frequency, values, std, systematic = channel(table, estimator, output, input_axis, systematic=True)
        floor = current_floor if estimator == "current" else position_floor
        systematic = np.where(np.isfinite(systematic), systematic, floor * np.abs(values))
        combined = np.hypot(std, systematic)
        weightless = ~(combined > 0)
        if weightless.any():
            raise CompareError(
                f"channel {estimator} {output}/{input_axis}: no uncertainty at {int(weightless.sum())} of "
                f"{weightless.size} frequencies (first {frequency[weightless][0]:.6g} Hz), so its misfit cannot be "
                "weighed: a noise-free log (a simulation) has none; add the measurement's noise to it")
        out[key] = (frequency, values, combined)
    if not out:
        raise CompareError("the FRF table holds no channel to compare")
    return out


def _compared(table):
    """The table's channels `measured_channels` compares: ``(output, input) -> (estimator, output, input)``."""
    logged = set(table[["estimator", "output", "input"]].itertuples(index=False, name=None))
    radial = "mimo" if any(row[0] == "mimo" for row in logged) else "siso"
    wanted = [(radial, o, i) for o in RADIAL_AXES for i in RADIAL_AXES if radial == "mimo" or o == i]
    wanted += [("siso", AXIAL_AXIS, AXIAL_AXIS)] + [("current", a, a) for a in ALL_AXES]
    return {(current_channel(row[1]) if row[0] == "current" else row[1], row[2]): row
            for row in wanted if row in logged}


class PointShares(NamedTuple):
    """What one channel's points count for at the floor, in frequency order (`effective_shares`)."""

    share: np.ndarray  #: each point's share of an independent point (its noise's and its stated variance's sharing)
    variance_error: np.ndarray  #: the variance of its stated variance's relative error, with its shared covariances


def effective_shares(table):
    """Each point's share of an independent point, channel by channel as `measured_channels` gives them.

    The FRF table's ``effective_share`` and ``variance_error``
    (`ambid.amplitude.zero_amplitude`: below 1 and above 0 where the
    extrapolation to zero amplitude makes points share their repeats' noise and
    noise estimates), 1 and 0 where the table has none (a table of another
    writer).  What a cell of the diagnosis counts for its chance limit
    (`ambid.diagnose.chance_limit`; `ambid.diagnose.diagnose` checks them).

    Returns
    -------
    dict
        ``(output, input) -> PointShares``.
    """
    return {key: PointShares(*channel(table, *row, share=True)[-2:]) for key, row in _compared(table).items()}


def input_coupling_slopes(table):
    """How each channel's values at zero amplitude move per unit input cross coupling, where they do.

    The FRF stage extrapolates a MIMO cross element to zero amplitude with the
    error the four diagonal elements predict for it, which depends on an input
    cross coupling it cannot know (`ambid.amplitude._mimo_inversion_errors`); it
    states the derivative in the table (``input_coupling_slope_re`` / ``_im``).

    Returns
    -------
    dict
        ``(output, input) -> complex array`` in `measured_channels`' order, for
        the channels with a nonzero slope (none for a table of another writer or
        a run without repeated steps).
    """
    out = {}
    for key, row in _compared(table).items():
        slope = channel(table, *row, coupling=True)[-1]
        if np.any(slope != 0):
            out[key] = slope
    return out


def input_coupling(effects):
    """The input cross coupling of ``effects``: the x-y element of the input-side coupling matrix the loop applies
    (`ambid.sampled_loop.coupling_matrix`; two couplings in series, ``(I + a S)(I + b S)``, give ``a + b``)."""
    return float(coupling_matrix([e for e in effects if e is not None], "input", ("DX", "DY"))[0, 1])


def at_input_coupling(measured, slopes, coefficient):
    """`measured_channels` as a model with input cross coupling ``coefficient`` reads them: each channel of
    ``slopes`` (`input_coupling_slopes`) moved by ``coefficient`` times its slope; the others as they are."""
    if not slopes or coefficient == 0:
        return measured
    return {key: (frequency, values + coefficient * slopes[key], std) if key in slopes else (frequency, values, std)
            for key, (frequency, values, std) in measured.items()}


def model_response(plant, channels):
    """The model's response on each channel of `measured_channels`, as the measurement sees it.

    Positions: the plant's FRF times the zero-order hold (`model_channels`).  Coil
    currents: the amplifier chain of the axis (the `COIL_CURRENT_EFFECTS`)
    discretized exactly with the hold and sampled as the machine's
    ``coil_current_sampling`` says (`sampled_chain`): at the start of the cycle,
    one cycle behind without an amplifier, or averaged over the cycle.

    Parameters
    ----------
    plant : ambid.plant.Plant
    channels : dict
        ``(output, input) -> (frequency_hz, ...)``; only the frequencies are used.
    """
    out = {}
    radial = [key for key in channels if key[0] in RADIAL_AXES]
    by_grid = {}
    for key in radial:
        by_grid.setdefault(channels[key][0].tobytes(), []).append(key)
    for keys in by_grid.values():
        out.update(model_channels(plant, channels[keys[0]][0], keys))
    if (AXIAL_AXIS, AXIAL_AXIS) in channels and plant.machine.axial_electromagnet is not None:
        frequency = channels[(AXIAL_AXIS, AXIAL_AXIS)][0]
        out[(AXIAL_AXIS, AXIAL_AXIS)] = plant.axial_frequency_response(frequency) * zero_order_hold(
            frequency, plant.machine.sample_time_s)
    for axis in ALL_AXES:
        key = (current_channel(axis), axis)
        if key in channels:
            out[key] = _sampled_coil_current(plant, axis, channels[key][0])
    return out


_SAMPLED_CHAINS = {}  # the coil-current response by (chain, sampling, sample time, grid): shared by every plant (a
#                       diagnosis rebuilds the plant at each evaluation; the amplifier chain rarely changes with it)


def _sampled_coil_current(plant, axis, frequency_hz):
    chain = [e for e in plant.input_effects if e.name in COIL_CURRENT_EFFECTS and e.acts_on(axis)]
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    sampling = plant.machine.coil_current_sampling
    sampling = DEFAULT_SAMPLING if sampling == "auto" else sampling
    key = (repr(chain), sampling, plant.machine.sample_time_s, frequency_hz.tobytes())
    if key not in _SAMPLED_CHAINS:
        if len(_SAMPLED_CHAINS) >= 1024:
            _SAMPLED_CHAINS.clear()
        response = sampled_chain(chain, plant.machine.sample_time_s, frequency_hz, sampling)
        response.flags.writeable = False
        _SAMPLED_CHAINS[key] = response
    return _SAMPLED_CHAINS[key]


def sampled_chain(chain, sample_time_s, frequency_hz, sampling=DEFAULT_SAMPLING):
    """The logged coil current against the command U2 of an amplifier chain driven through the hold.

    The chain ``x' = A x + B u``, ``i = C x + D u`` is discretized exactly over
    the cycle ``T`` (``Phi = e^(AT)``, ``Gamma``), with ``x_k`` the state when
    command ``u_k`` is output.  What the log pairs with ``u_k`` depends on when
    the current is measured (`COIL_CURRENT_SAMPLING`):

    * ``start_of_cycle``, sampled with the positions before the cycle's command
      acts (the PLC reads its inputs first; ambid's rig):
      ``C (zI - Phi)^-1 Gamma + D / z``, an ideal amplifier one cycle behind;
    * ``cycle_average``, the mean over the cycle of the command (a drive's own
      measurement, integrated over its period):
      ``C M_x (zI - Phi)^-1 Gamma + C M_u + D`` with ``M_x = (1/T) int_0^T e^(As) ds``
      and ``M_u = (1/T) int_0^T int_0^s e^(Ar) dr ds B``; an ideal amplifier is U2 itself.

    Parameters
    ----------
    chain : list of Effect
        `COIL_CURRENT_EFFECTS` in series (empty: an ideal amplifier).
    sample_time_s : float
    frequency_hz : array_like
    sampling : str
        One of `COIL_CURRENT_SAMPLING`.
    """
    if sampling not in COIL_CURRENT_SAMPLING:
        raise CompareError(f"coil-current sampling {sampling!r} is not one of {', '.join(COIL_CURRENT_SAMPLING)}")
    a, b, c, d = series_state_space([e.siso_state_space() for e in chain])
    z = np.exp(2j * np.pi * np.asarray(frequency_hz, dtype=float) * sample_time_s)
    n = a.shape[0]
    if n == 0:
        return d[0, 0] / z if sampling == "start_of_cycle" else np.full(z.shape, d[0, 0], dtype=complex)
    if sampling == "start_of_cycle":
        transition, gamma = zoh_discretize(a, b, sample_time_s)
        output, feedthrough = c, d[0, 0] / z
    else:
        # Van Loan: expm([[F, I], [0, 0]] T) holds int_0^T e^(Fs) ds, F = [[A, B], [0, 0]] the held input's system
        m = n + 1
        augmented = np.zeros((2 * m, 2 * m))
        augmented[:n, :n], augmented[:n, n:m], augmented[:m, m:] = a, b, np.eye(m)
        exponential = scipy.linalg.expm(augmented * sample_time_s)
        transition, gamma = exponential[:n, :n], exponential[:n, n:m]
        mean_state, mean_input = exponential[:n, m:m + n] / sample_time_s, exponential[:n, m + n:] / sample_time_s
        output, feedthrough = c @ mean_state, (c @ mean_input)[0, 0] + d[0, 0]
    resolvent = np.linalg.solve(z[:, None, None] * np.eye(n) - transition, gamma.astype(complex))
    return (output @ resolvent)[:, 0, 0] + feedthrough


class _SecondOrderAmplifier:
    """A current loop of second order, ``w^2 / (s^2 + 2 zeta w s + w^2)``: a family the coil-current sampling fit tries
    beside the first-order `AmplifierLowpass` (not an effect of the library)."""

    def __init__(self, natural_hz, damping_ratio):
        self.natural_hz, self.damping_ratio = natural_hz, damping_ratio

    def siso_state_space(self):
        w = 2 * np.pi * self.natural_hz
        return (np.array([[0.0, w], [-w, -2 * self.damping_ratio * w]]), np.array([[0.0], [w]]), np.array([[1.0, 0.0]]),
                np.array([[0.0]]))


#: Damping ratios the second-order family is scanned at before its refinement.
SECOND_ORDER_DAMPING = (0.15, 0.3, 0.5, 0.7, 1.0)


def coil_current_sampling_fit(measured, sample_time_s):
    """How well each coil-current sampling convention explains a run's coil currents, the amplifier fitted with it.

    The sampling convention and a current loop both make the coil current lag the
    command (one cycle is 50 us; a 2.5 kHz first-order loop lags 64 us at low
    frequency), but only the loop's roll-off changes the magnitude.  So each
    convention is fitted with its best amplifier common to all axes: none, a
    first-order `AmplifierLowpass` (a log-spaced scan over 50 Hz - 1 MHz and a
    bounded refinement) or a second-order loop (natural frequency scanned over
    the same range at the damping ratios `SECOND_ORDER_DAMPING`, then refined with
    both free), on every coil-current channel, weighted by the measured
    uncertainty.  Without the second order, a second-order loop's lag at low
    frequency reads as the start-of-cycle convention with a first-order loop (the
    independent rig's 2 kHz, damping 0.5 amplifier on averaged currents: chi2
    1.0e6 against 2.3e6, the wrong convention).

    Parameters
    ----------
    measured : dict
        `measured_channels`; only the ``I_<axis>`` channels are used.
    sample_time_s : float

    Returns
    -------
    dict or None
        ``sampling -> (chi2, amplifier)`` with ``amplifier`` a dict: ``order`` (0: none, 1, 2), ``cutoff_hz``
        (first order), ``natural_hz`` and ``damping_ratio`` (second order); ``"first_order"``: ``sampling -> chi2``
        of the best amplifier of the library's family (none or first order); and ``"points"``.  None without
        coil-current channels.
    """
    import scipy.optimize  # here, not at the top: ~0.2 s of import in every rule that reads this module

    channels = [value for (output, axis), value in measured.items() if output == current_channel(axis)]
    if not channels:
        return None
    frequency = np.concatenate([f for f, _, _ in channels])
    values = np.concatenate([v for _, v, _ in channels])
    std = np.concatenate([s for _, _, s in channels])
    grid, index = np.unique(frequency, return_inverse=True)
    first_order = EFFECTS["amplifier_lowpass"]

    def chi2(sampling, chain):
        response = sampled_chain(chain, sample_time_s, grid, sampling)[index]
        return float(np.sum(np.abs((response - values) / std) ** 2))

    def first(sampling, x):
        return chi2(sampling, [first_order(cutoff_hz=float(np.exp(x)))])

    def second(sampling, x):
        return chi2(sampling, [_SecondOrderAmplifier(float(np.exp(x[0])), float(x[1]))])

    out = {"points": int(values.size), "first_order": {}}
    scan = np.linspace(np.log(50.0), np.log(1e6), 61)
    for sampling in COIL_CURRENT_SAMPLING:
        fits = [(chi2(sampling, []), {"order": 0})]
        trials = [first(sampling, x) for x in scan]
        best = int(np.argmin(trials))
        refined = scipy.optimize.minimize_scalar(lambda x: first(sampling, x), method="bounded",
                                                 bounds=(scan[max(best - 1, 0)], scan[min(best + 1, scan.size - 1)]),
                                                 options={"xatol": 1e-4})
        fits.append((float(refined.fun), {"order": 1, "cutoff_hz": float(np.exp(refined.x))}))
        out["first_order"][sampling] = min(f[0] for f in fits)
        trials = [(second(sampling, (x, zeta)), x, zeta) for x in scan[::2] for zeta in SECOND_ORDER_DAMPING]
        _, x, zeta = min(trials)
        refined = scipy.optimize.minimize(lambda y: second(sampling, y), [x, zeta], method="L-BFGS-B",
                                          bounds=[(scan[0], scan[-1]), (0.05, 2.0)])
        fits.append((float(refined.fun), {"order": 2, "natural_hz": float(np.exp(refined.x[0])),
                                          "damping_ratio": float(refined.x[1])}))
        out[sampling] = min(fits, key=lambda f: f[0])
    return out


def amplifier_text(amplifier):
    """An amplifier of `coil_current_sampling_fit` in words."""
    if amplifier["order"] == 0:
        return "an ideal amplifier"
    if amplifier["order"] == 1:
        return f"a {amplifier['cutoff_hz']:.4g} Hz amplifier low-pass"
    return (f"a second-order current loop of {amplifier['natural_hz']:.4g} Hz, damping ratio "
            f"{amplifier['damping_ratio']:.2g} (no effect of the library)")


def with_coil_current_sampling(machine, measured, stage):
    """The machine with the coil-current sampling convention this run's data follow, and what the user must know.

    ``controller.coil_current_sampling: auto`` (the default) takes the convention
    whose fit (`coil_current_sampling_fit`) has the least chi2, where the two differ
    by more than `SAMPLING_EVIDENCE` (10, the diagnosis' indistinguishable evidence); otherwise, or
    without coil-current channels, ``start_of_cycle``.  A machine file that names
    its convention keeps it, with a warning where the data follow the other.  A
    log written by other software may pair each coil current with the same
    cycle's command, not the one before: read with the wrong convention, every
    coil-current channel misfits by up to ``2 sin(pi f T)`` (16 % at 500 Hz and
    50 us) and no effect of the library explains it.  Where the chosen convention's
    currents follow a second-order current loop better than any first-order one (by
    more than `SAMPLING_EVIDENCE`), a ``coil_current_loop`` note says so: the library
    holds the first order only.

    Returns
    -------
    machine : ambid.machine.Machine
        ``coil_current_sampling`` resolved (never ``auto``).
    findings : list of Finding
    """
    fit = coil_current_sampling_fit(measured, machine.sample_time_s)
    stated = machine.coil_current_sampling
    if fit is None:
        return replace(machine, coil_current_sampling=DEFAULT_SAMPLING if stated == "auto" else stated), []
    machine, findings = _sampling_decision(machine, fit, stated, stage)
    sampling = machine.coil_current_sampling
    chi2, amplifier = fit[sampling]
    best = min(COIL_CURRENT_SAMPLING, key=lambda s: fit[s][0])
    # (read with the convention the data contradict, the second order mimics the other's part of a cycle: no note)
    if sampling == best and amplifier["order"] == 2 and fit["first_order"][sampling] - chi2 > SAMPLING_EVIDENCE:
        points = fit["points"]
        findings.append(Finding(stage, "note", "coil_current_loop", "coil currents",
                                f"this run's coil currents follow {amplifier_text(amplifier)}: chi2/pt {chi2 / points:.3g} "
                                f"against {fit['first_order'][sampling] / points:.3g} with the best first-order amplifier "
                                f"low-pass ({sampling}); the coil-current channels misfit by what the library's "
                                "first-order amplifier cannot follow", fit["first_order"][sampling] - chi2))
    return machine, findings


def _sampling_decision(machine, fit, stated, stage):
    """`with_coil_current_sampling`'s choice of convention from its ``fit``, and the finding that says so."""
    best, other = sorted(COIL_CURRENT_SAMPLING, key=lambda s: fit[s][0])
    decisive = fit[other][0] - fit[best][0] > SAMPLING_EVIDENCE
    points = fit["points"]

    def told(sampling):
        chi2, amplifier = fit[sampling]
        return f"{sampling} chi2/pt {chi2 / points:.3g} (with {amplifier_text(amplifier)})"

    key = "controller.coil_current_sampling"
    if stated == "auto":
        chosen = best if decisive else DEFAULT_SAMPLING
        if chosen == DEFAULT_SAMPLING and decisive:
            return replace(machine, coil_current_sampling=chosen), []
        message = (f"the coil currents of this run are read as {SAMPLING_TOLD[chosen]}: {told(best)} against "
                   f"{told(other)}"
                   + ("" if decisive else "; the data do not tell the two apart, so the default is used")
                   + f" ({key}: auto; name it in the machine file to fix it)")
        return replace(machine, coil_current_sampling=chosen), [
            Finding(stage, "note", "coil_current_sampling", key, message, fit[other][0] - fit[best][0])]
    if decisive and best != stated:
        message = (f"the machine file says the coil currents are {SAMPLING_TOLD[stated]}, but this run's are "
                   f"{SAMPLING_TOLD[best]}: {told(best)} against {told(stated)}; every coil-current channel misfits "
                   f"until {key} says {best} (or auto)")
        return machine, [Finding(stage, "warning", "coil_current_sampling", key, message, fit[stated][0] - fit[best][0])]
    return machine, []


def for_run(machine, measured, frf_metadata, stage):
    """The machine as one run measures it, and what the user must know: at the run's excitation level
    (`at_run_level`), with enough retained modes (`with_enough_modes`) and the run's coil-current sampling
    (`with_coil_current_sampling`).  What rules `compare` and `diagnose` model a run with.

    Returns
    -------
    machine : ambid.machine.Machine
    findings : list of Finding
    """
    machine, level = at_run_level(machine, frf_metadata, stage)
    machine, modes = with_enough_modes(machine, measured, stage)
    machine, sampling = with_coil_current_sampling(machine, measured, stage)
    return machine, level + excitation_against_bias(machine, frf_metadata, stage) + modes + sampling


#: A stepped sine whose excitation exceeds this fraction of an axis' bias current is said to (`excitation_against_bias`).
EXCITATION_BIAS_FRACTION = 0.5


def excitation_against_bias(machine, frf_metadata, stage):
    """A warning for each axis the run excited beyond `EXCITATION_BIAS_FRACTION` of its bias current on the drawing.

    The FRF stage takes a stepped sine to zero amplitude on the ``A^2`` law of the force law's describing function
    (`ambid.amplitude`), and states its error on that law.  Near the bias current the law fails (one coil's current
    swings to zero): on demo20's rig at the thesis' 3 A, its whole bias, the zero-amplitude FRF kept up to 0.24 % of
    error above 700 Hz, 10-110 times what it stated (`benchmarks/bench_amplitude_limit.py`), a droop a diagnosis can
    read as a sensor pole.  The FRF stage is model-free and cannot tell; the machine file can.

    Returns
    -------
    list of Finding
    """
    peaks = (frf_metadata or {}).get("peak_excitation_a") or {}
    bias = dict(zip(ALL_AXES, machine.bias_currents_a))
    repeated = (frf_metadata or {}).get("repeated_steps", 0)
    why = ("the force law's describing function there leaves the A^2 law by which the FRF stage extrapolates the "
           "repeated steps to zero amplitude, so the FRF carries more error than it states" if repeated else
           "the FRF is the describing function at that amplitude (no step was repeated lower), whose error grows faster "
           "than A^2 there and stays in it")
    findings = []
    for axis, amplitude in peaks.items():
        ratio = amplitude / bias.get(axis, np.inf)
        if ratio > EXCITATION_BIAS_FRACTION * (1 + 1e-9):
            findings.append(Finding(
                stage, "warning", "excitation_near_bias", axis,
                f"the run excited {axis} at up to {amplitude:.3g} A, {ratio:.2f} of its {bias[axis]:.3g} A bias current, "
                f"where one coil's current swings toward zero: {why} (a droop toward high frequency, which a sensor pole "
                "imitates; benchmarks/bench_amplitude_limit.py). Identify at most half the bias current "
                "(identification.max_bias_fraction), or read high-frequency findings with care.", float(ratio)))
    return findings


def model_channels(plant, frequency_hz, channels):
    """The model's radial FRF of each channel as the identification measures it (times the ZOH) [m/A]."""
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    response = plant.radial_frequency_response(frequency_hz) * zero_order_hold(frequency_hz,
                                                                                plant.machine.sample_time_s)[:, None, None]
    return {(o, i): response[:, RADIAL_AXES.index(o), RADIAL_AXES.index(i)] for o, i in channels}


def truncation_error(machine, measured, retained_modes, reference):
    """Largest error of the radial channels with ``retained_modes`` modes against ``reference``, in units of sigma.

    The modal model keeps the lowest ``retained_modes`` free-free modes per plane
    (thesis eq. 2.10); the modes it drops still bend the response below their
    frequencies (most near anti-resonances, which are set by every mode).  The
    error is ``max |G_n - G_ref| / sigma`` over the measured radial points, and
    the point where it is largest.

    Returns
    -------
    error : float
        In units of the measurement's uncertainty.
    magnitude_db, phase_deg, frequency_hz : float
        The model-to-model difference at that point.
    """
    radial = {key: value for key, value in measured.items() if key[0] in RADIAL_AXES}
    if not radial:
        return 0.0, 0.0, 0.0, 0.0
    reduced = model_response(Plant(replace(machine, retained_modes=retained_modes)), radial)
    full = reference if isinstance(reference, dict) else model_response(Plant(replace(machine, retained_modes=reference)), radial)
    worst = (0.0, 0.0, 0.0, 0.0)
    for key, (frequency, _, std) in radial.items():
        difference = np.abs(reduced[key] - full[key]) / std
        k = int(np.argmax(difference))
        if difference[k] > worst[0]:
            ratio = reduced[key][k] / full[key][k] if full[key][k] != 0 else 1.0
            worst = (float(difference[k]), float(20 * np.log10(abs(ratio))), float(np.degrees(np.angle(ratio))), float(frequency[k]))
    return worst


def enough_modes(machine, measured, tolerance=0.1, most=80):
    """The retained modes that keep the truncation error below ``tolerance`` times the floor on every measured point.

    Starting from the machine's own ``retained_modes`` and growing by half each
    time, against a reference of ``most`` modes (or all the rotor has).

    Returns
    -------
    modes : int
        The number to use (the machine's own when it is enough).
    own_error : tuple
        `truncation_error` of the machine's own number.
    error : tuple
        `truncation_error` of ``modes`` (above ``tolerance`` only when even ``most`` modes are not enough).
    """
    available = 2 * machine.rotor.n_nodes
    most = min(most, available)
    own = machine.retained_modes
    if own >= most:
        return own, (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)
    radial = {key: value for key, value in measured.items() if key[0] in RADIAL_AXES}
    reference = model_response(Plant(replace(machine, retained_modes=most)), radial)
    own_error = truncation_error(machine, measured, own, reference)
    modes, error = own, own_error
    while error[0] > tolerance and modes < most:
        modes = min(most, int(np.ceil(1.5 * modes)))
        error = truncation_error(machine, measured, modes, reference) if modes < most else (0.0, 0.0, 0.0, 0.0)
    return modes, own_error, error


def at_run_level(machine, frf_metadata, stage):
    """The machine as a run at a finite excitation level measures it, where the run's FRF states the level.

    A multisine's BLA is the bearing linearized at the mean of the force law
    over the run's currents and positions (`ambid.effects.at_excitation_level`);
    its FRF stage records their covariance (``excitation_covariance``,
    `ambid.bla.excitation_covariance`; ``excitation_current`` ``U2`` where the log has no coil currents).  Runs without it (stepped sine: its FRF is
    taken to zero amplitude instead, `ambid.amplitude`) keep the machine as it is.

    Returns
    -------
    machine : ambid.machine.Machine
    findings : list of Finding
        A note with the stiffness factors applied.
    """
    excitation = (frf_metadata or {}).get("excitation_covariance")
    if not excitation:
        return machine, []
    shifted = at_excitation_level(machine, excitation)
    before, after = Plant(machine), Plant(shifted)
    kx = after.position_stiffness / before.position_stiffness
    ki = after.current_stiffness / before.current_stiffness
    currents = ("logged coil currents" if frf_metadata.get("excitation_current", "coil") == "coil" else
                "logged control currents U2, as the log has no coil currents (above the amplifiers' bandwidth U2 "
                "overstates them, and so the shift)")
    message = (f"the model is linearized at the run's excitation level (thesis eq. 3.6 averaged over the {currents} "
               "and positions): position stiffness x " + ", ".join(f"{a} {f:.4f}" for a, f in zip(RADIAL_AXES, kx))
               + "; current stiffness x " + ", ".join(f"{a} {f:.4f}" for a, f in zip(RADIAL_AXES, ki)))
    return shifted, [Finding(stage, "note", "excitation_level", "bearings", message, float(np.max(np.abs(kx - 1))))]


def with_enough_modes(machine, measured, stage, tolerance=0.1):
    """The machine with enough retained modes for this measurement (`enough_modes`), and what the user must know.

    Returns
    -------
    machine : ambid.machine.Machine
    findings : list of ambid.findings.Finding
        A warning when the machine's own ``rotor.retained_modes`` leaves a
        truncation error above the tolerance (and the number used instead), or
        when even the most modes tried do not reach it.
    """
    modes, own, error = enough_modes(machine, measured, tolerance)
    findings = []
    if modes != machine.retained_modes:
        findings.append(Finding(stage, "warning", "truncation", "rotor.retained_modes",
                                f"{machine.retained_modes} retained modes leave a truncation error of {own[0]:.3g} times the "
                                f"measurement's uncertainty ({own[1]:+.2f} dB, {own[2]:+.2f} deg near {own[3]:.0f} Hz); this "
                                f"stage used {modes}: set rotor.retained_modes: {modes} in the machine file", own[0]))
    if error[0] > tolerance:
        findings.append(Finding(stage, "warning", "truncation", "rotor.retained_modes",
                                f"even {modes} modes leave a truncation error of {error[0]:.3g} times the uncertainty "
                                f"({error[1]:+.2f} dB near {error[3]:.0f} Hz)", error[0]))
    return replace(machine, retained_modes=modes), findings


def channel_errors(measured, model):
    """Errors of the model against the measurement, one row per channel and frequency.

    Parameters
    ----------
    measured : dict (output, input) -> (frequency_hz, values, std)
    model : dict (output, input) -> values on the same frequencies

    Returns
    -------
    pandas.DataFrame
        ``output, input, frequency_hz, magnitude_error_db, phase_error_deg, normalized_error``; the
        magnitude and phase errors are NaN where the measurement or the model is inside the noise
        (``|G| <= RESOLVED std``, `ambid.floor.RESOLVED`: 3).
    """
    rows = []
    for (output, input_axis), (frequency, values, std) in measured.items():
        if (output, input_axis) not in model:
            continue
        predicted = np.asarray(model[(output, input_axis)])
        if predicted.shape != values.shape:
            raise CompareError(f"channel {output}/{input_axis}: model and measurement have different frequencies")
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise CompareError(f"channel {output}/{input_axis}: the measurement has no positive, finite uncertainty")
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = predicted / values
        # a channel the model (or data) lacks, or a point inside the noise on either side (a decoupled plane's cross
        # channel: the noise against the model's round-off, 100 dB and more), has no magnitude or phase error
        resolved = np.isfinite(ratio) & (ratio != 0) & (np.minimum(np.abs(values), np.abs(predicted)) > RESOLVED * std)
        ratio = np.where(resolved, ratio, np.nan)
        rows.append(pd.DataFrame({"output": output, "input": input_axis, "frequency_hz": frequency,
                                  "magnitude_error_db": 20 * np.log10(np.abs(ratio)),
                                  "phase_error_deg": np.degrees(np.angle(ratio)),
                                  "normalized_error": np.abs(predicted - values) / std}))
    if not rows:
        raise CompareError("no channel is both measured and modelled")
    return pd.concat(rows, ignore_index=True)


def summarize(errors, bands_hz=None):
    """One row per channel and band, per channel (band ``all``) and overall (channel ``all``).

    Parameters
    ----------
    errors : pandas.DataFrame
        `channel_errors`.
    bands_hz : sequence, optional
        Band edges (the last may be ``inf``); default: per channel family, bands
        derived from the measured grid (`ambid.floor.frequency_bands`), so no band
        lies outside the data or holds a handful of points.

    Returns
    -------
    pandas.DataFrame
        Columns ``output, input, band, points, chi2, excess, rms_magnitude_db, rms_phase_deg``;
        ``chi2`` is the mean squared normalized error (1: at the floor), ``excess = max(chi2 - 1, 0)``.
    """
    band = np.empty(len(errors), dtype=object)
    families = errors["output"].map(channel_family).to_numpy()
    for family in np.unique(families):
        rows = families == family
        frequency = errors["frequency_hz"].to_numpy()[rows]
        edges = np.asarray(bands_hz, dtype=float) if bands_hz is not None else frequency_bands(frequency)
        labels = band_labels(edges)
        index = np.clip(np.searchsorted(edges, frequency, side="right") - 1, 0, len(labels) - 1)
        band[rows] = np.asarray(labels, dtype=object)[index]
    outputs, inputs = errors["output"].to_numpy(dtype=object), errors["input"].to_numpy(dtype=object)
    channel, channels = pd.factorize(pd.Series(list(zip(outputs, inputs)), dtype=object))
    cell, cells = pd.factorize(pd.Series(list(zip(outputs, inputs, band)), dtype=object))
    # each channel's bands in the order the grid meets them, then the channel over all bands (channels in the order of
    # the errors), the overall row last; the means skip the points without a magnitude or phase error (no signal)
    groups = [(cell, list(cells)), (channel, [(*key, "all") for key in channels]),
              (np.zeros(len(errors), dtype=int), [("all", "all", "all")])]
    squares = {"chi2": errors["normalized_error"].to_numpy(dtype=float) ** 2,
               "magnitude": errors["magnitude_error_db"].to_numpy(dtype=float) ** 2,
               "phase": errors["phase_error_deg"].to_numpy(dtype=float) ** 2}
    parts = []
    for code, keys in groups:
        part = pd.DataFrame(keys, columns=["output", "input", "band"])
        part["points"] = np.bincount(code, minlength=len(keys))
        for name, values in squares.items():
            finite = np.isfinite(values)
            with np.errstate(invalid="ignore", divide="ignore"):
                part[name] = (np.bincount(code, np.where(finite, values, 0.0), minlength=len(keys))
                              / np.bincount(code, finite, minlength=len(keys)))
        parts.append(part)
    position = {key: k for k, key in enumerate(channels)}
    parts[0]["position"], parts[1]["position"] = [position[key[:2]] for key in cells], np.arange(len(channels))
    rows = pd.concat(parts[:2], ignore_index=True).sort_values("position", kind="stable").drop(columns="position")
    rows = pd.concat([rows, parts[2]], ignore_index=True)
    return pd.DataFrame({"output": rows["output"].astype(errors["output"].dtype),
                         "input": rows["input"].astype(errors["input"].dtype), "band": rows["band"].astype(errors["output"].dtype),
                         "points": rows["points"].astype(int), "chi2": rows["chi2"],
                         "excess": np.maximum(rows["chi2"] - 1.0, 0.0),
                         "rms_magnitude_db": np.sqrt(rows["magnitude"]), "rms_phase_deg": np.sqrt(rows["phase"])})
