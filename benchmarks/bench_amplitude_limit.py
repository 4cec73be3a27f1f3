"""Accuracy study: the stepped sine's excitation amplitude against the bias current (``identification.max_bias_fraction``).

The FRF stage extrapolates each repeated step to zero amplitude on the assumption that the describing function departs
from the linearized plant as ``A^2`` (`ambid.amplitude`).  The force law (thesis eq. 3.6) is quadratic in each coil's
current ``i_b +- i``: the departure is a series in ``(A / i_b)^2``, and at ``A`` near ``i_b`` one coil's current
reaches zero and clips.  Here a rig of each default machine without a hidden effect, without sensor noise and ADC
quantization (so the only error left is what the ``A^2`` law leaves), is identified on the diagnosis benchmark's grid
(80 radial points from 1 Hz) with the amplitude capped at the thesis' ``amplitude_max_a`` alone (3 A; the bias current
is 3 A on demo20's radial bearings, 5 A on hs_eden_like's) and at 0.5 and 0.33 of the bias current.  Printed per band,
for the DX/DX element at zero amplitude against the rig's linearized truth (`ambid.rig.RigModel.sampled_frequency_response`,
the scorer's only use of the rig): the median and largest relative error, and the same in units of the standard
deviation the FRF stage states for the point (noise and systematic floor); and the describing function's own error at
the measured amplitude (level 0, ``frf.zero_amplitude`` off).

Usage: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_amplitude_limit.py`` (about a minute).
Measured at stop 52 (seed 2060):

- demo20, 3 A: above 700 Hz error median 0.072 %, 16.5 of its standard deviation (largest 110); at 1.5 A (0.5 of the
  bias) 0.002 %, 0.5 (largest 1.7); at 1.0 A the same;
- hs_eden_like, 3 A (0.6 of its bias): 200-700 Hz largest 11.5 standard deviations; at 2.5 A 5.9, at 1.67 A 4.0
  (single steps beside a resonance); elsewhere every step within 3.0, medians 0.4-1.0.
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_diagnose as suite  # noqa: E402  (the suite's config, grids and FRF settings)

from ambid.compare import measured_channels  # noqa: E402
from ambid.excitation import StepPlan, amplitude_limits, run_stepped_sine, settings_from_config  # noqa: E402
from ambid.experiment import hidden_effect_rig, identification_frame  # noqa: E402
from ambid.floor import FloorSettings  # noqa: E402
from ambid.frf import frf_from_log  # noqa: E402
from ambid.machine import machine_from_config  # noqa: E402
from ambid.plant import Plant  # noqa: E402
from ambid.rig import RigModel  # noqa: E402

BANDS_HZ = ((0.0, 200.0), (200.0, 700.0), (700.0, np.inf))


def errors(machine, fraction, seed=2060):
    """DX/DX at zero amplitude and at the measured amplitude against the rig's linearized truth, per step."""
    config = suite.machine_config(machine, 80)
    rig = hidden_effect_rig(config, [], sensor_noise_m=1e-12, current_noise_a=1e-10, sensor_resolution_m=0.0,
                            current_resolution_a=0.0)  # (a trace of noise: the FRF stage needs a stated one)
    settings = dataclasses.replace(settings_from_config(suite.CONFIG["identification"]), max_bias_fraction=fraction)
    plant = Plant(machine_from_config(config))
    records, _ = run_stepped_sine(RigModel(rig), StepPlan.for_machine(plant, settings), settings, seed=seed)
    frame = identification_frame(records)
    floor = FloorSettings.from_config({k: v for k, v in suite.CONFIG["frf"].items() if k not in suite.FRF_SETTINGS})
    zero, level = (measured_channels(frf_from_log(frame, dataclasses.replace(floor, zero_amplitude=on))[0])[("DX", "DX")]
                   for on in (True, False))
    frequency, value, std = zero
    truth = RigModel(rig).sampled_frequency_response(frequency)[:, 0, 0]
    limit = amplitude_limits(plant.machine, settings)[0]
    return limit, frequency, np.abs(value / truth - 1), np.abs(value - truth) / std, np.abs(level[1] / truth - 1)


def main():
    print("DX/DX against the rig's linearized truth, noise-free rig: relative error median / largest, "
          "and in stated standard deviations")
    for machine in ("demo20", "hs_eden_like"):
        for fraction in (None, 0.5, 1 / 3):
            limit, frequency, relative, z, described = errors(machine, fraction)
            print(f"  {machine:<13} cap {'none' if fraction is None else f'{fraction:.2f} bias'} ({limit:.2f} A)")
            for low, high in BANDS_HZ:
                band = (frequency >= low) & (frequency < high)
                print(f"    {low:5.0f}-{'' if np.isinf(high) else f'{high:.0f}':<5} Hz: zero amplitude {100 * np.median(relative[band]):.4f} / "
                      f"{100 * relative[band].max():.4f} %, {np.median(z[band]):.1f} / {z[band].max():.1f} std; "
                      f"describing function {100 * np.median(described[band]):.3f} %")


if __name__ == "__main__":
    main()
