"""Virtual experiments: a rig with chosen hidden effects, identified straight to an FRF table.

What the ``acquire_identification`` and ``frf`` rules do through files, in one
call, for studies that try many hidden effects (the diagnosis test suite and
its benchmark).  The truth is built here and handed only to the rig; the
model side receives the FRF table.
"""

import numpy as np

from .errors import ModelError
from .excitation import StepPlan, run_stepped_sine
from .frf import frf_from_log
from .logs import identification_frame
from .machine import ALL_AXES, BEARINGS, RADIAL_AXES, machine_from_config
from .plant import Plant
from .rig import RigModel, rig_from_config

__all__ = ["SIGNATURE_FLOOR", "effect_signature", "measured_floor", "hidden_effect_draws", "hidden_effect_rig",
           "identify_on_rig"]


#: Relative floor of the signature of a hidden effect (`effect_signature`): what the stepped sine typically resolves.
SIGNATURE_FLOOR = {"positions": 0.01, "currents": 0.003}


def effect_signature(machine, effects, floor=None):
    """How far ``effects`` move the model's response, in units of the data floor: the largest ``|dG| / sigma``.

    A hidden effect of signature 3 changes some point by three times the floor:
    the weak end of what a diagnosis should see.

    Parameters
    ----------
    machine : ambid.machine.Machine
    effects : sequence of ambid.effects.Effect
    floor : dict, optional
        The floor measured in a log of ``machine`` without the effects, ``{(output, input): (frequency_hz, sigma)}``
        (`measured_floor`): the signature on every channel of that log, at its frequencies, in units of its
        ``sigma``.  Without it, a typical floor over the radial matrix, the axial channel and the coil currents of
        ``machine``'s grids: ``sigma = floor max(|G|, |G_oo| / 10)``, the relative floors of `SIGNATURE_FLOOR` and
        ``G_oo`` the output's own diagonal response.  That typical floor is far from a measured one: on
        hs_eden_like's rig (seed 2051, 80 points) the coil currents' measured floor is about a fiftieth of it, and at
        a diagonal's anti-resonance, where ``G_oo`` vanishes with ``G``, the measured floor is up to 130 times it
        (the noise of the positions does not vanish there), so a drawn effect could change no measured point by more
        than 0.4 of its floor and still have a typical signature of 11.
    """
    from .compare import model_response
    from .diagnose import plant_with_effects

    plant = Plant(machine)
    if floor is not None:
        keys = {key: (frequency,) for key, (frequency, _) in floor.items()}
    else:
        radial, axial = machine.radial_grid.frequency_hz, machine.axial_grid.frequency_hz
        keys = {(o, i): (radial,) for o in RADIAL_AXES for i in RADIAL_AXES}
        keys[("Z", "Z")] = (axial,)
        keys.update({(f"I_{a}", a): (radial,) for a in RADIAL_AXES})
    before = model_response(plant, keys)
    after = model_response(plant_with_effects(plant, list(effects)), keys)
    worst = 0.0
    for key, values in before.items():
        if floor is not None:
            sigma = floor[key][1]
        else:
            relative = SIGNATURE_FLOOR["currents" if key[0].startswith("I_") else "positions"]
            row = np.abs(before[(key[0], key[0])]) if key[0] in RADIAL_AXES else np.abs(values)
            sigma = relative * np.maximum(np.abs(values), 0.1 * row)
        worst = max(worst, float(np.max(np.abs(after[key] - values) / sigma)))
    return worst


def measured_floor(table):
    """The floor of an identification's FRF table as `effect_signature` reads it: ``{(output, input): (frequency_hz,
    sigma)}`` of every channel the diagnosis reads (`ambid.compare.measured_channels`: noise and systematic floor)."""
    from .compare import measured_channels

    return {key: (frequency, sigma) for key, (frequency, _, sigma) in measured_channels(table).items()}


def _log_bisection(holds, inside, outside, steps):
    """The last value where ``holds`` is true, bisecting on a log scale from ``inside`` (true) towards ``outside``."""
    lo, hi = np.log(inside), np.log(outside)
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if holds(np.exp(mid)):
            lo = mid
        else:
            hi = mid
    return float(np.exp(lo))


def _weak_end(machine, build, strong, weak, target=3.0, floor=None):
    """The strength between ``strong`` and ``weak`` (log scale) where the signature falls to ``target``."""
    if effect_signature(machine, [build(weak)], floor) >= target:
        return weak
    return _log_bisection(lambda v: effect_signature(machine, [build(v)], floor) >= target, strong, weak, 30)


def _admissible(plant):
    """Whether a truth could be a commissioned machine: its closed loop stable and no axis in ISO 14839-3 zone D."""
    from .loop import stability_summary

    try:
        rows = stability_summary(plant)
    except ModelError:
        return False
    return all(row["stable"] and row["iso_14839_zone"] != "D" for row in rows)


def _admissible_end(machine, build, strong, end):
    """The strongest strength between ``strong`` and ``end`` (log scale) at which the machine stays `_admissible`.

    ``end`` (the weak end) is taken as admissible; a tenth of the log distance to it is kept as margin from
    the boundary, so a draw does not sit on the edge of instability.
    """
    from .diagnose import plant_with_effects

    plant = Plant(machine)

    def admissible(strength):
        return _admissible(plant_with_effects(plant, [build(strength)]))

    if admissible(strong):
        return strong
    boundary = np.log(_log_bisection(admissible, end, strong, 24))
    return float(np.exp(boundary + 0.1 * (np.log(end) - boundary)))


def hidden_effect_draws(machine_config, seed=2026, target=3.0, floor=None):
    """One hidden effect per library entry, its strength drawn from physical ranges down to a signature of ``target``.

    Physical ranges of AMB machines: amplifier bandwidth from 500 Hz, controller
    delay up to 200 us, sensor bandwidth from 1 kHz, eddy-current corner from
    300 Hz, x-y coupling up to 5 % (either sign, input or output side), the
    stiffness of a random element group between 0.3 and 1.5 times nominal,
    added modal damping up to 0.02, speed up to 40 000 rpm, sensor shifts up to
    40 mm (either direction), a housing mode at 100-600 Hz (damping 0.01-0.05)
    from 5 kg, the bearings' force constants and bias currents off by up to 10 %
    (each axis its own share of the drawn error).  Each strength is drawn log-uniformly between its strong end and
    the weak end where `effect_signature` falls to ``target`` times the floor,
    so the draws include effects barely above what the data resolve.  The strong
    end is pulled back where it would leave no commissioned machine (a closed
    loop unstable or in ISO 14839-3 zone D, `_admissible_end`): a machine that
    cannot levitate is not identified.

    Parameters
    ----------
    machine_config : dict
    seed : int
    target : float
        The weak end's signature.
    floor : dict, optional
        The floor measured in a log of the machine without an effect (`measured_floor`): the signature in units of it
        (the issue's "down to three times the data floor"); without it, a typical floor (`effect_signature`).

    Returns
    -------
    dict
        ``{effect name: parameters}``, plus ``"signature"``: ``{effect name: signature}``.
    """
    from .effects import effect_from_config

    machine = machine_from_config(machine_config)
    rng = np.random.default_rng(seed)
    tags = sorted({tag for element in machine.rotor.elements for tag in element.tags})

    def effect(name, parameters):
        return effect_from_config({"name": name, "parameters": parameters}, name, machine)

    def draw(name, key, strong, weak, fixed=None, transform=lambda v: v, build=None):
        """Parameters with ``key`` drawn between ``strong`` and the weak end (``transform=None``: the strength itself)."""
        fixed = fixed or {}
        build = build or (lambda v: effect(name, {**fixed, key: transform(v)}))
        end = _weak_end(machine, build, strong, weak, target, floor)
        strong = _admissible_end(machine, build, strong, end)
        value = float(np.exp(rng.uniform(*sorted((np.log(strong), np.log(end))))))
        return value if transform is None else {**fixed, key: transform(value)}

    sign = lambda: float(rng.choice([-1.0, 1.0]))  # noqa: E731
    stiffer = rng.random() < 0.3
    shift_sign = (sign(), sign())
    sensors = [machine.bearing(name).sensor_position_m for name in BEARINGS]
    room = min(sensors[0] if shift_sign[0] < 0 else machine.rotor.length_m - sensors[0],
               sensors[1] if shift_sign[1] < 0 else machine.rotor.length_m - sensors[1])
    draws = {
        "amplifier_lowpass": draw("amplifier_lowpass", "cutoff_hz", 500.0, 1e6),
        "delay": draw("delay", "delay_s", 200e-6, 1e-9),
        "sensor_lowpass": draw("sensor_lowpass", "cutoff_hz", 1000.0, 1e6),
        "eddy_current": draw("eddy_current", "corner_hz", 300.0, 1e6),
        "cross_coupling": draw("cross_coupling", "coefficient", 0.05, 1e-6, {"side": str(rng.choice(["input", "output"]))},
                               transform=lambda v, s=sign(): s * v),
        "element_stiffness": draw("element_stiffness", "scale", 0.5 if stiffer else 1 / 0.3, 1e-6,
                                  {"tag": str(rng.choice(tags))},
                                  transform=lambda v, up=stiffer: float(np.exp(v)) if up else float(np.exp(-v))),
        "modal_damping": draw("modal_damping", "damping_ratio", 0.02, 1e-7),
        "gyroscopic": draw("gyroscopic", "speed_rpm", 40000.0, 1.0),
        # at most 4 cm, and on the rotor with both sensors (the NDE shift is up to 1.5 times the DE one)
        "noncollocation": draw("noncollocation", "de_offset_m", min(0.04, 0.6 * room), 1e-7,
                               transform=lambda v: v * shift_sign[0]),
        "foundation_mode": draw("foundation_mode", "mass_kg", 5.0, 1e5,
                                {"frequency_hz": float(rng.uniform(100, 600)), "damping_ratio": float(rng.uniform(0.01, 0.05))}),
    }
    spread = rng.uniform(-1.0, 1.0, size=(2, len(ALL_AXES)))  # each axis' force-constant and bias errors, relative
    actuator = draw("actuator_coefficients", "error", 0.1, 1e-7, transform=None,
                    build=lambda e: effect("actuator_coefficients", {"force_constant_scale": tuple(1 + e * spread[0]),
                                                                     "bias_current_scale": tuple(1 + e * spread[1])}))
    draws["actuator_coefficients"] = {"force_constant_scale": tuple(float(v) for v in 1 + actuator * spread[0]),
                                      "bias_current_scale": tuple(float(v) for v in 1 + actuator * spread[1])}
    draws["noncollocation"]["nde_offset_m"] = shift_sign[1] * abs(draws["noncollocation"]["de_offset_m"]) * float(rng.uniform(0.5, 1.5))
    draws["signature"] = {name: effect_signature(machine, [effect(name, parameters)], floor)
                          for name, parameters in draws.items()}
    return draws


def hidden_effect_rig(machine_config, effects, sensor_noise_m=2e-7, current_noise_a=5e-3, name="hidden_effect_rig",
                      unmodelled=(), sensor_resolution_m=5e-8, current_resolution_a=1e-3):
    """A rig whose truth is the machine plus ``effects`` (``effects:`` entries), centred and weightless.

    ``unmodelled`` entries add physics outside the model's library (`ambid.rig_effects`).

    Noise and ADC quantization as on the default rig (0 turns either off); no magnetic-center offset,
    gravity or bias-current error, so the rig sits at the operating point the
    nominal model assumes (a calibrated machine) and only the hidden effects
    separate truth from model.
    """
    rig_config = {
        "name": name,
        "machine": machine_config.get("name", "machine"),
        "truth": {
            "effects": list(effects),
            "unmodelled": list(unmodelled),
            "gravity_m_s2": 0.0,
            "sensor_noise_m": sensor_noise_m,
            "sensor_resolution_m": sensor_resolution_m,
            "current_noise_a": current_noise_a,
            "current_resolution_a": current_resolution_a,
        },
    }
    return rig_from_config(rig_config, machine_config, source=name)


def identify_on_rig(rig, machine_config, settings, seed=0, setpoint_m=None, floor_settings=None):
    """The stepped-sine identification of ``rig`` planned on the nominal machine, as an FRF table.

    Parameters
    ----------
    rig : ambid.rig.Rig
    machine_config : dict
        The engineer's machine (plans the grid and the start amplitudes).
    settings : ambid.excitation.SteppedSineSettings
    seed : int
        Seed of the measurement noise.
    setpoint_m : array (5,), optional
        Position set points (the calibrated magnetic center).
    floor_settings : ambid.floor.FloorSettings, optional
        How the FRF stage measures the floor (config ``frf``).

    Returns
    -------
    pandas.DataFrame
        `ambid.frf.frf_table` with SISO, MIMO and coil-current estimates.
    """
    plan = StepPlan.for_machine(Plant(machine_from_config(machine_config)), settings)
    records, _ = run_stepped_sine(RigModel(rig, setpoint_m), plan, settings, seed=seed)
    table, _, _ = frf_from_log(identification_frame(records), floor_settings)
    return table
