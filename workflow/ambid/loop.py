"""Closed-loop transfer functions (thesis Table 4.1) and stability margins.

Thesis Table 4.1 writes the controller ``C`` (V1 -> U1) with the feedback sign
inside it; with our PID ``C_pid`` (error -> current) that is ``C = -C_pid``::

    input sensitivity      E  -> V1   (I - P C)^-1
    dynamic compliance     Eu -> V2   (I - P C)^-1 P
    dynamic stiffness      V2 -> Eu   P^-1 - C
    output sensitivity     Eu -> U2   (I - C P)^-1
    open loop (Nyquist)    V1 -> V2   P C

Stability is judged two ways: the eigenvalues of the sampled-data closed loop
with every effect of the model (`ambid.plant.Plant.closed_loop_poles`, the loop
the virtual rig simulates: delays, low-passes, eddy-current lag,
cross-coupling) and the peak of the sensitivity function per axis, graded by
the zones of ISO 14839-3 (A < 9.5 dB, B < 12 dB, C < 14 dB, D above).  A
sensitivity peak grades a stable loop only: an unstable loop is "unstable"
and has no zone.
"""

import functools

import numpy as np

from .errors import ModelError
from .machine import AXIAL_AXIS, RADIAL_AXES
from .plant import damping_ratio

__all__ = ["transfer_functions", "axial_transfer_functions", "stability_summary", "iso_zone", "zero_order_hold",
           "check_stable"]

ISO_14839_ZONES = ((3.0, "A"), (4.0, "B"), (5.0, "C"))


def iso_zone(sensitivity_peak):
    """ISO 14839-3 zone of a sensitivity peak (linear magnitude)."""
    for limit, zone in ISO_14839_ZONES:
        if sensitivity_peak < limit:
            return zone
    return "D"


def _functions(plant_response, controller_response):
    """Table 4.1 from P (n_f, n, n) and the decentralized C = -C_pid, array (n_f, n)."""
    n = plant_response.shape[-1]
    identity = np.eye(n)
    controller = controller_response[:, :, None] * identity
    open_loop = plant_response @ controller
    input_sensitivity = np.linalg.inv(identity - open_loop)
    return {
        "controller": controller,
        "open_loop": open_loop,
        "input_sensitivity": input_sensitivity,
        "dynamic_compliance": input_sensitivity @ plant_response,
        "dynamic_stiffness": np.linalg.inv(plant_response) - controller,
        "output_sensitivity": np.linalg.inv(identity - controller @ plant_response),
    }


def zero_order_hold(frequency_hz, sample_time_s):
    """``(1 - exp(-s T)) / (s T)``: the DAC's hold seen by the continuous plant (1 at DC); read-only."""
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    return _hold(frequency_hz.tobytes(), frequency_hz.shape, float(sample_time_s))


@functools.lru_cache(maxsize=256)  # by grid and sample time: a diagnosis asks for the same hold at every evaluation
def _hold(grid_bytes, shape, sample_time_s):
    x = 2j * np.pi * np.frombuffer(grid_bytes).reshape(shape) * sample_time_s
    safe = np.where(x == 0, 1.0, x)
    hold = np.where(x == 0, 1.0, (1 - np.exp(-safe)) / safe)
    hold.flags.writeable = False
    return hold


def transfer_functions(plant, frequency_hz, hold=False):
    """The transfer functions of thesis Table 4.1 for the radial axes.

    Parameters
    ----------
    plant : ambid.plant.Plant
    frequency_hz : array (n_f,)
    hold : bool
        Include the zero-order hold of the digital loop in the plant (for margins
        of the real sampled loop; the identified plant U2 -> V2 contains it too).

    Returns
    -------
    dict of arrays (n_f, 4, 4)
        ``plant``, ``controller``, ``open_loop``, ``input_sensitivity``,
        ``dynamic_compliance``, ``dynamic_stiffness``, ``output_sensitivity``.
    """
    plant_response = plant.radial_frequency_response(frequency_hz)
    if hold:
        plant_response = plant_response * zero_order_hold(frequency_hz, plant.machine.sample_time_s)[:, None, None]
    controller = -np.stack([c.frequency_response(frequency_hz) for c in plant.machine.radial_controllers], axis=1)
    return {"plant": plant_response, **_functions(plant_response, controller)}


def axial_transfer_functions(plant, frequency_hz, hold=False):
    """Table 4.1 for the axial axis; arrays (n_f, 1, 1)."""
    plant_response = plant.axial_frequency_response(frequency_hz)[:, None, None]
    if hold:
        plant_response = plant_response * zero_order_hold(frequency_hz, plant.machine.sample_time_s)[:, None, None]
    controller = -plant.machine.axial_controller.frequency_response(frequency_hz)[:, None]
    return {"plant": plant_response, **_functions(plant_response, controller)}


def stability_summary(plant, frequency_hz=None):
    """Closed-loop stability and sensitivity margins per axis.

    Parameters
    ----------
    plant : ambid.plant.Plant
    frequency_hz : array, optional
        Where to search the sensitivity peak; default 1 Hz to the Nyquist
        frequency of the controller, 4000 log-spaced points.

    The sensitivity and the eigenvalue check both include the zero-order hold of
    the sampled loop and every effect of the model (delays, low-passes, the
    eddy-current lag, cross-coupling).

    Returns
    -------
    list of dict
        One row per axis: ``axis``, ``spectral_radius`` of the sampled-data closed
        loop (< 1 is stable), ``stable``, ``verdict`` ("stable" / "unstable"),
        ``min_damping_ratio`` of its oscillatory poles (the loop's weakest mode;
        radial axes share one loop), ``sensitivity_peak_db``,
        ``sensitivity_peak_hz``, ``iso_14839_zone`` (empty for an unstable loop:
        the sensitivity of a loop that diverges grades nothing).
    """
    machine = plant.machine
    radial_loop = plant.closed_loop_poles()
    if frequency_hz is None:
        nyquist = 0.5 / machine.sample_time_s
        frequency_hz = np.logspace(0, np.log10(0.999 * nyquist), 4000)
        # lightly damped closed-loop modes have peaks narrower than any grid: look at them too
        poles = radial_loop.s_poles[np.isfinite(radial_loop.s_poles)]
        damped = np.abs(poles.imag[(poles.imag > 0) & (damping_ratio(poles) < 0.2)]) / (2 * np.pi)
        frequency_hz = np.unique(np.concatenate([frequency_hz, damped[damped < nyquist]]))
    rows = []
    radial = transfer_functions(plant, frequency_hz, hold=True)["input_sensitivity"]
    for k, axis in enumerate(RADIAL_AXES):
        rows.append(_row(axis, radial_loop, np.abs(radial[:, k, k]), frequency_hz))
    if machine.axial_electromagnet is not None:
        axial = axial_transfer_functions(plant, frequency_hz, hold=True)["input_sensitivity"]
        rows.append(_row(AXIAL_AXIS, plant.axial_closed_loop_poles(), np.abs(axial[:, 0, 0]), frequency_hz))
    return rows


def check_stable(plant, what):
    """Raise `ModelError` when the sampled-data closed loop of ``plant`` (radial, and Z) is unstable.

    A machine that levitates while it is measured cannot have a model whose loop diverges: such a model
    variant has no ISO 14839-3 zone and nothing downstream of it (plant FRF, comparison, diagnosis) is
    meaningful.  ``what`` names the model in the message (its machine file and variant).
    """
    loops = [("DX, DY, NX, NY", plant.closed_loop_poles())]
    if plant.machine.axial_electromagnet is not None:
        loops.append(("Z", plant.axial_closed_loop_poles()))
    unstable = [(axes, loop.spectral_radius) for axes, loop in loops if loop.spectral_radius >= 1.0]
    if unstable:
        radii = ", ".join(f"{radius:.6f} on {axes}" for axes, radius in unstable)
        raise ModelError(f"{what} is unstable in closed loop (spectral radius {radii}: the sampled loop with every effect "
                         "of the model, delays and low-passes included), so it has no ISO 14839-3 zone and describes no "
                         "levitating machine; check the controller gains and filters of the machine file and the delays, "
                         "low-passes and eddy-current effects the variant adds")


def _row(axis, closed_loop, sensitivity, frequency_hz):
    peak = int(np.argmax(sensitivity))
    spectral_radius = closed_loop.spectral_radius
    s = closed_loop.s_poles
    s = s[np.isfinite(s)]  # the delay buffer's poles at z = 0
    oscillatory = s[np.abs(s.imag) > 1e-9 * np.maximum(np.abs(s), 1.0)]
    stable = bool(spectral_radius < 1.0)
    return {
        "axis": axis,
        "spectral_radius": float(spectral_radius),
        "stable": stable,
        "verdict": "stable" if stable else "unstable",
        "min_damping_ratio": float(np.min(damping_ratio(oscillatory))) if oscillatory.size else 1.0,
        "sensitivity_peak_db": float(20 * np.log10(sensitivity[peak])),
        "sensitivity_peak_hz": float(frequency_hz[peak]),
        "iso_14839_zone": iso_zone(sensitivity[peak]) if stable else "",
    }
