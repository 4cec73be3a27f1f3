"""Commissioning views: the measured sensitivity with its ISO 14839-3 zone and margins, and the Campbell diagram.

The stepped-sine identification excites each axis at the controller output,
``E_u = A sin(2 pi f t)`` (thesis eq. 4.2, `ambid.excitation`), and logs the
Fourier coefficient of the control current ``U2`` at the excitation frequency
with its phase referred to the start of the excitation.  The excitation is
known, so the output sensitivity ``S = U2 / E_u`` of each axis (thesis Table
4.1, `ambid.loop`) is measured directly: ``E_u`` has the complex amplitude
``-j A`` in that convention.  With the other loops closed, ``S`` is the
loop-at-a-time sensitivity of that axis, ``S = 1 / (1 + L)``, so its loop gain
``L = 1/S - 1`` gives the gain and phase margins; the peak of ``|S|`` is the
quantity ISO 14839-3 grades (zones A/B/C/D below 9.5 / 12 / 14 dB,
`ambid.loop.iso_zone`).

The levitated rotor's mode shapes are the closed loop's structural eigenvectors
at standstill (the bearings' negative stiffness and the controllers' stiffness
and damping included), not the free-free modes of the model file.

The Campbell diagram is the closed loop's natural frequencies over rotor speed
(`ambid.plant.Plant.at_speed`: the gyroscopic coupling splits each planar mode
into a forward and a backward whirl), with the synchronous line 1x.
"""

import numpy as np
import pandas as pd

from .errors import AmbidError
from .loop import ISO_14839_ZONES, axial_transfer_functions, iso_zone, transfer_functions
from .machine import AXIAL_AXIS, RADIAL_AXES
from .plant import RIGID_MODES, damping_ratio

__all__ = ["ISO_ZONE_LIMITS_DB", "measured_sensitivity", "model_sensitivity", "excitation_check", "loop_margins",
           "sensitivity_rows", "campbell", "levitated_modes"]

#: ISO 14839-3 zone limits of the sensitivity peak [dB]: A/B, B/C, C/D (20 log10 of 3, 4, 5).
ISO_ZONE_LIMITS_DB = tuple((float(20 * np.log10(limit)), zone) for limit, zone in ISO_14839_ZONES)


def measured_sensitivity(frame):
    """Output sensitivity ``U2 / E_u`` of each excited axis from a stepped-sine identification log.

    Parameters
    ----------
    frame : pandas.DataFrame
        The log (`ambid.logs.read_identification_log`): ``excited_axis``,
        ``frequency_hz``, ``amplitude_a``, ``channel``, ``re``, ``im``,
        ``noise_std`` and optionally ``level`` (only level 0 is used).

    Returns
    -------
    dict axis -> (frequency_hz, sensitivity, std)
        Complex ``S`` and the standard deviation of its noise, sorted by frequency.
    """
    if "level" in frame.columns:
        frame = frame[frame["level"] == 0]
    out = {}
    for axis, part in frame.groupby("excited_axis", sort=False):
        rows = part[part["channel"] == f"U2_{axis}"].sort_values("frequency_hz")
        if rows.empty:
            continue
        amplitude = rows["amplitude_a"].to_numpy(float)
        if np.any(amplitude <= 0):
            raise AmbidError(f"axis {axis}: an excitation amplitude <= 0 gives no sensitivity")
        excitation = -1j * amplitude  # A sin(w t) as a phasor referred to the start of the excitation
        u2 = rows["re"].to_numpy(float) + 1j * rows["im"].to_numpy(float)
        out[str(axis)] = (rows["frequency_hz"].to_numpy(float), u2 / excitation, rows["noise_std"].to_numpy(float) / amplitude)
    return {axis: out[axis] for axis in (*RADIAL_AXES, AXIAL_AXIS) if axis in out}


def model_sensitivity(plant, frequency_hz):
    """The model's output sensitivity ``Eu -> U2`` of each axis (diagonal of thesis Table 4.1, zero-order hold included).

    Returns
    -------
    dict axis -> complex array (n_f,)
    """
    radial = transfer_functions(plant, frequency_hz, hold=True)["output_sensitivity"]
    out = {axis: radial[:, k, k] for k, axis in enumerate(RADIAL_AXES)}
    if plant.machine.axial_electromagnet is not None:
        out[AXIAL_AXIS] = axial_transfer_functions(plant, frequency_hz, hold=True)["output_sensitivity"][:, 0, 0]
    return out


def excitation_check(measured, plant, factor=30.0):
    """Whether a log's measured sensitivity can be graded: the reasons it cannot, in words (empty: it can).

    ``S = U2 / E_u`` needs the excitation's amplitude in A and the phases referred
    to the start of the excitation (the log contract).  A log from another writer
    may lack either, and ``|S|`` then grades any loop, however poor, in zone A:

    * ``amplitude_a`` equal to ``|U2|`` at every step: a table without the column
      (the import takes ``|U2|`` in its place), ``|S| = 1`` by construction;
    * ``|S|`` a factor ``factor`` or more off the model's below 0.3 x the first
      flexible mode (where a model's sensitivity is right within a few %: 2-5 % on
      the rigs' logs), e.g. the amplitude in mA;
    * phases more than 60 degrees off the model's there (0.7-1.4 degrees on the
      rigs' logs): the zone stands (it reads ``|S|``), the margins (they read the
      phase of ``L = 1/S - 1``) do not.

    Parameters
    ----------
    measured : dict
        `measured_sensitivity` of the log.
    plant : ambid.plant.Plant
        A model of the machine (the nominal variant).
    factor : float
        How far ``|S|`` may be from the model's.

    Returns
    -------
    grade, margins : str
        Why the zone (``grade``) or the margins cannot be given; empty where they can.
    """
    if not measured:
        return "", ""
    if all(np.allclose(np.abs(s), 1.0, rtol=1e-9, atol=0) for _, s, _ in measured.values()):
        return ("the log's excitation amplitude is |U2| at every step (a table without amplitude_a: the import takes "
                "|U2| in its place), so |S| = 1 by construction; log amplitude_a to grade the loop"), ""
    first_flexible_hz = plant.modes.frequency_hz[RIGID_MODES]
    ratio, phase = [], []
    for axis, (frequency, sensitivity, _) in measured.items():
        low = frequency <= 0.3 * first_flexible_hz
        low = low if np.count_nonzero(low) >= 3 else np.ones_like(low)
        model = model_sensitivity(plant, frequency[low]).get(axis)
        if model is None:
            continue
        ratio.append(np.abs(sensitivity[low] / model))
        phase.append(np.abs(np.angle(sensitivity[low] / model)))
    if not ratio:
        return "", ""
    ratio, phase = float(np.median(np.concatenate(ratio))), float(np.degrees(np.median(np.concatenate(phase))))
    if not 1 / factor < ratio < factor:
        unit = " (it looks like mA)" if 2.5 < -np.log10(ratio) < 3.5 else ""
        return (f"|S| is {ratio:.3g} times the model's below {0.3 * first_flexible_hz:.0f} Hz (0.3 x its first flexible "
                f"mode), where a model's sensitivity is right within a few %: amplitude_a is not the excitation's "
                f"amplitude in A{unit}"), ""
    if phase > 60.0:
        return "", (f"the phase of S is {phase:.0f} degrees off the model's below {0.3 * first_flexible_hz:.0f} Hz: the "
                    "log's phases are not referred to the start of the excitation A sin(w t) (the log contract), so the "
                    "loop gain's phase, and the margins, are unknown")
    return "", ""


def _crossings(x, y, level):
    """Linear interpolation of x where y crosses ``level`` (y finite)."""
    sign = np.sign(y - level)
    k = np.flatnonzero(sign[:-1] * sign[1:] < 0)
    return k, (level - y[k]) / (y[k + 1] - y[k])


def loop_margins(frequency_hz, sensitivity):
    """Gain and phase margins of the loop gain ``L = 1/S - 1`` of one axis on a frequency grid.

    An AMB loop stabilizes an unstable plant, so it has two gain margins: where
    the phase of ``L`` crosses 180 degrees with ``|L| < 1`` the gain may grow by
    ``1/|L|`` (upper margin, positive dB), where it crosses with ``|L| > 1`` it
    may shrink by as much (lower margin, negative dB).  The phase margin is the
    smallest distance of the phase of ``L`` from 180 degrees where ``|L|``
    crosses 1.  Crossings are interpolated between grid points (log frequency);
    NaN where the grid shows none (e.g. beyond the measured band).

    Returns
    -------
    dict
        ``upper_gain_margin_db``, ``upper_gain_margin_hz``, ``lower_gain_margin_db``,
        ``lower_gain_margin_hz``, ``phase_margin_deg``, ``phase_margin_hz``.
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    loop = 1.0 / np.asarray(sensitivity) - 1.0
    log_f = np.log10(frequency_hz)
    out = dict.fromkeys(("upper_gain_margin_db", "upper_gain_margin_hz", "lower_gain_margin_db", "lower_gain_margin_hz",
                         "phase_margin_deg", "phase_margin_hz"), np.nan)
    # phase crossover: L real and negative, i.e. Im L changes sign with Re L < 0
    k, t = _crossings(log_f, loop.imag, 0.0)
    real = loop.real[k] + t * (loop.real[k + 1] - loop.real[k])
    at_hz = 10 ** (log_f[k] + t * (log_f[np.minimum(k + 1, log_f.size - 1)] - log_f[k]))
    margins = -20 * np.log10(np.maximum(np.abs(real), 1e-300))
    for name, pick, best in (("upper", (real < 0) & (margins > 0), np.argmin), ("lower", (real < 0) & (margins <= 0), np.argmax)):
        if pick.any():
            j = int(best(margins[pick]))
            out[f"{name}_gain_margin_db"] = float(margins[pick][j])
            out[f"{name}_gain_margin_hz"] = float(at_hz[pick][j])
    k, t = _crossings(log_f, np.log10(np.maximum(np.abs(loop), 1e-300)), 0.0)
    if k.size:
        value = loop[k] + t * (loop[k + 1] - loop[k])
        margins = 180.0 - np.abs(np.degrees(np.angle(value)))
        j = int(np.argmin(margins))
        out["phase_margin_deg"] = float(margins[j])
        out["phase_margin_hz"] = float(10 ** (log_f[k[j]] + t[j] * (log_f[k[j] + 1] - log_f[k[j]])))
    return out


def sensitivity_rows(curves, source):
    """Peak, ISO 14839-3 zone and margins of each axis' sensitivity; one row per axis.

    Parameters
    ----------
    curves : dict axis -> (frequency_hz, sensitivity)
    source : str
        ``measured`` or the model variant's name (a column of the rows).
    """
    rows = []
    for axis, (frequency, sensitivity) in curves.items():
        magnitude = np.abs(sensitivity)
        peak = int(np.argmax(magnitude))
        rows.append({"axis": axis, "source": source, "sensitivity_peak_db": float(20 * np.log10(magnitude[peak])),
                     "sensitivity_peak_hz": float(frequency[peak]), "iso_14839_zone": iso_zone(magnitude[peak]),
                     **loop_margins(frequency, sensitivity)})
    return rows


def campbell(plant, speeds_rpm, max_frequency_hz, min_participation=1e-3):
    """Closed-loop natural frequencies over rotor speed (the Campbell diagram).

    Parameters
    ----------
    plant : ambid.plant.Plant
    speeds_rpm : array
    max_frequency_hz : float

    Returns
    -------
    pandas.DataFrame
        ``speed_rpm``, ``frequency_hz`` (damped, Im s / 2 pi), ``damping_ratio``,
        ``whirl`` (forward / backward / planar) of every oscillatory closed-loop
        pole below ``max_frequency_hz`` with a plant participation of at least
        ``min_participation`` (structural modes; the suspension modes share
        their energy with the controller states, so the threshold is low;
        controller and filter poles have none).
    """
    rows = []
    n_q = plant.radial.mass.shape[0]
    for speed in np.asarray(speeds_rpm, dtype=float):
        spinning = plant.at_speed(speed * 2 * np.pi / 60)
        closed = spinning.closed_loop_poles()
        finite = np.isfinite(closed.s_poles)
        poles, vectors = closed.s_poles[finite], closed.vectors[:, finite]
        participation = closed.plant_participation[finite]
        zeta = damping_ratio(poles)
        for k, pole in enumerate(poles):
            frequency = pole.imag / (2 * np.pi)
            if frequency <= 1e-6 or frequency > max_frequency_hz or participation[k] < min_participation:
                continue
            _, whirl = spinning.mode_kind(vectors[:n_q, k])
            rows.append({"speed_rpm": float(speed), "frequency_hz": float(frequency), "damping_ratio": float(zeta[k]),
                         "whirl": whirl if speed > 0 else "planar"})
    return pd.DataFrame(rows, columns=["speed_rpm", "frequency_hz", "damping_ratio", "whirl"])


def levitated_modes(plant, count=4, max_frequency_hz=np.inf, min_participation=1e-3):
    """Mode shapes of the levitated rotor: the lowest structural modes of the closed loop at standstill.

    Parameters
    ----------
    plant : ambid.plant.Plant
    count : int
        Modes returned at most (x plane; at standstill the y plane has the same ones).
    max_frequency_hz : float
        Modes above are left out.
    min_participation : float
        Plant participation below which a pole is a controller or filter pole (see `campbell`).

    Returns
    -------
    frequency_hz : array (n,)
        Damped natural frequencies.
    damping : array (n,)
    displacement : array (n_nodes, n)
        Real displacement along the rotor (x plane), phase-aligned so that its
        largest component is real and positive, normalized to unit peak.
    """
    standstill = plant.at_speed(0.0) if plant.machine.speed_rad_s else plant
    closed = standstill.closed_loop_poles()
    finite = np.isfinite(closed.s_poles)
    poles, vectors, participation = closed.s_poles[finite], closed.vectors[:, finite], closed.plant_participation[finite]
    n_modes = standstill.modes.shapes.shape[1]
    u = standstill.modes.shapes[0::2]
    zeta = damping_ratio(poles)
    picked = []
    for k in np.argsort(np.abs(poles.imag)):
        if poles[k].imag <= 1e-6 or participation[k] < min_participation or poles[k].imag > 2 * np.pi * max_frequency_hz:
            continue
        ex, ey = vectors[:n_modes, k], vectors[n_modes:2 * n_modes, k]
        frequency = poles[k].imag / (2 * np.pi)
        if np.sum(np.abs(ex) ** 2) < np.sum(np.abs(ey) ** 2) or any(abs(frequency - f) <= 1e-3 * f for f, _, _ in picked):
            continue  # the y-plane twin (at standstill a degenerate pair may mix the planes: the same frequency)
        shape = u @ ex
        shape = shape * np.exp(-1j * np.angle(shape[np.argmax(np.abs(shape))]))
        picked.append((frequency, zeta[k], shape.real / np.max(np.abs(shape.real))))
        if len(picked) == count:
            break
    if not picked:
        return np.zeros(0), np.zeros(0), np.zeros((u.shape[0], 0))
    frequency, damping, shapes = zip(*picked)
    return np.array(frequency), np.array(damping), np.column_stack(shapes)
