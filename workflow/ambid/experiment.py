"""Virtual experiments: a rig with chosen hidden effects, identified straight to an FRF table.

What the ``acquire_identification`` and ``frf`` rules do through files, in one
call, for studies that try many hidden effects (the diagnosis test suite and
its benchmark).  The truth is built here and handed only to the rig; the
model side receives the FRF table.
"""

import numpy as np

from .excitation import StepPlan, run_stepped_sine
from .frf import current_etfe, frf_table, log_arrays, mimo_etfe, siso_etfe
from .logs import identification_frame
from .machine import machine_from_config
from .plant import Plant
from .rig import RigModel, rig_from_config

__all__ = ["hidden_effect_draws", "hidden_effect_rig", "identify_on_rig"]


def hidden_effect_draws(seed=2026):
    """Parameters of one hidden effect per library entry, drawn uniformly from physical ranges of AMB machines.

    Amplifier bandwidth 0.5-3 kHz, controller delay 50-200 us, sensor bandwidth
    1-5 kHz, eddy-current corner 0.5-5 kHz, x-y coupling 0.5-5 % (either sign,
    input or output side), lamination-stack (``de_amb``) stiffness 30-100 %,
    added modal damping 0.003-0.02, speed 10 000-40 000 rpm, sensor shifts
    5-40 mm (either direction), housing mode 100-600 Hz of 5-30 kg with damping
    ratio 0.01-0.05.  Returns ``{effect name: parameters}``.
    """
    rng = np.random.default_rng(seed)

    def uniform(lower, upper):
        return float(rng.uniform(lower, upper))

    def sign():
        return float(rng.choice([-1.0, 1.0]))

    return {
        "amplifier_lowpass": {"cutoff_hz": uniform(500, 3000)},
        "delay": {"delay_s": uniform(50e-6, 200e-6)},
        "sensor_lowpass": {"cutoff_hz": uniform(1000, 5000)},
        "eddy_current": {"corner_hz": uniform(500, 5000)},
        "cross_coupling": {"coefficient": sign() * uniform(0.005, 0.05), "side": str(rng.choice(["input", "output"]))},
        "element_stiffness": {"tag": "de_amb", "scale": uniform(0.3, 1.0)},
        "modal_damping": {"damping_ratio": uniform(0.003, 0.02)},
        "gyroscopic": {"speed_rpm": uniform(10000, 40000)},
        "noncollocation": {"de_offset_m": sign() * uniform(0.005, 0.04), "nde_offset_m": sign() * uniform(0.005, 0.04)},
        "foundation_mode": {"frequency_hz": uniform(100, 600), "mass_kg": uniform(5, 30), "damping_ratio": uniform(0.01, 0.05)},
    }


def hidden_effect_rig(machine_config, effects, sensor_noise_m=2e-7, current_noise_a=5e-3, name="hidden_effect_rig"):
    """A rig whose truth is the machine plus ``effects`` (``effects:`` entries), centred and weightless.

    Noise and ADC quantization as on the default rig; no magnetic-center offset,
    gravity or bias-current error, so the rig sits at the operating point the
    nominal model assumes (a calibrated machine) and only the hidden effects
    separate truth from model.
    """
    rig_config = {
        "name": name,
        "machine": machine_config.get("name", "machine"),
        "truth": {
            "effects": list(effects),
            "gravity_m_s2": 0.0,
            "sensor_noise_m": sensor_noise_m,
            "sensor_resolution_m": 5e-8,
            "current_noise_a": current_noise_a,
            "current_resolution_a": 1e-3,
        },
    }
    return rig_from_config(rig_config, machine_config, source=name)


def identify_on_rig(rig, machine_config, settings, seed=0, setpoint_m=None):
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

    Returns
    -------
    pandas.DataFrame
        `ambid.frf.frf_table` with SISO, MIMO and coil-current estimates.
    """
    plan = StepPlan.for_machine(Plant(machine_from_config(machine_config)), settings)
    records, _ = run_stepped_sine(RigModel(rig, setpoint_m), plan, settings, seed=seed)
    arrays = log_arrays(identification_frame(records))
    return frf_table(siso_etfe(arrays), mimo_etfe(arrays), current=current_etfe(arrays))
