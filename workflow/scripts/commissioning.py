"""Rule `commissioning`: measured sensitivity per axis with ISO 14839-3 zone and margins beside the models', Campbell diagram."""

import numpy as np
import pandas as pd

from ambid.commissioning import (ISO_ZONE_LIMITS_DB, campbell, excitation_check, levitated_modes, measured_sensitivity,
                                 model_sensitivity, sensitivity_rows)
from ambid.io import read_tsv, read_yaml, rule_log, write_tsv
from ambid.logs import read_identification_log
from ambid.machine import machine_from_config
from ambid.plant import Plant, damping_ratio
from ambid.plots import campbell_diagram, mode_shapes, save_figure, sensitivity_zones

log = rule_log(snakemake.log[0], "commissioning")

machine_name, run = snakemake.wildcards.machine, snakemake.wildcards.run
frame, _ = read_identification_log(snakemake.input.log)
measured = measured_sensitivity(frame)
plants = {variant: Plant(machine_from_config(read_yaml(path), name=machine_name, source=path))
          for variant, path in zip(snakemake.params.variants, snakemake.input.models)}
ungraded, no_margins = excitation_check(measured, plants[snakemake.params.variants[0]])  # the nominal variant
graded = {} if ungraded else measured  # a zone A from a meaningless |S| would pass a poor loop
if ungraded:
    log.warning("measured sensitivity not graded: %s", ungraded)
    rows = [{"axis": axis, "source": "measured", "iso_14839_zone": "not graded", "note": ungraded} for axis in measured]
else:
    rows = sensitivity_rows({axis: (f, s) for axis, (f, s, _) in measured.items()}, "measured")
    if no_margins:
        log.warning("measured margins not given: %s", no_margins)
        margins = ("upper_gain_margin_db", "upper_gain_margin_hz", "lower_gain_margin_db", "lower_gain_margin_hz",
                   "phase_margin_deg", "phase_margin_hz")
        rows = [{**row, **dict.fromkeys(margins, np.nan), "note": no_margins} for row in rows]
curves = {}
for variant, plant in plants.items():
    nyquist = 0.5 / plant.machine.sample_time_s
    dense = np.logspace(0, np.log10(0.999 * nyquist), 2000)
    # lightly damped closed-loop modes have peaks narrower than any grid: evaluate at them too (as ambid.loop does)
    poles = plant.closed_loop_poles().s_poles
    poles = poles[np.isfinite(poles) & (poles.imag > 0)]
    damped = poles.imag[damping_ratio(poles) < 0.2] / (2 * np.pi)
    dense = np.unique(np.concatenate([dense, damped[damped < 0.999 * nyquist]]))
    model = model_sensitivity(plant, dense)
    curves[variant] = {axis: (dense, values) for axis, values in model.items()}
    on_grid = {axis: (f, model_sensitivity(plant, f)[axis]) for axis, (f, _, _) in measured.items() if axis in model}
    rows += sensitivity_rows(on_grid, f"{variant} (measured band)")
    rows += sensitivity_rows(curves[variant], f"{variant} (1 Hz to Nyquist)")
table = pd.DataFrame(rows).sort_values(["axis"], kind="stable")
write_tsv(table, snakemake.output.sensitivity)
for row in table.itertuples():
    log.info("%s %-28s peak %.2f dB at %.0f Hz (zone %s)", row.axis, row.source, row.sensitivity_peak_db,
             row.sensitivity_peak_hz, row.iso_14839_zone)
save_figure(sensitivity_zones(graded, curves, ISO_ZONE_LIMITS_DB,
                              f"{machine_name} {run}: sensitivity |U2/Eu| per axis, "
                              + ("modelled (measured not graded: see the table)" if ungraded else "measured and modelled")
                              + " (ISO 14839-3 zones)"),
            snakemake.output.sensitivity_figure, snakemake.params.dpi)

last = snakemake.params.variants[-1]
settings = snakemake.params.settings
speeds = np.linspace(*settings["campbell_speed_rpm"], settings["campbell_speeds"])
band_top = max(float(f.max()) for f, _, _ in measured.values()) if measured else 1000.0
max_frequency = min(0.5 / plants[last].machine.sample_time_s, max(2.5 * band_top, 1.2 * speeds.max() / 60))
modes = campbell(plants[last], speeds, max_frequency)
write_tsv(modes, snakemake.output.campbell)
features = read_tsv(snakemake.input.features)
# modes the fit identified: lightly damped, well determined, not flagged (the features the model update uses)
resonances = features[(features["estimator"] == "output_error") & (features["kind"] == "resonance")
                      & features["damping_ratio"].between(0, 0.2)
                      & (features["frequency_std_hz"] < 0.01 * features["frequency_hz"])]
if "flag" in resonances.columns:
    resonances = resonances[resonances["flag"].isna() | (resonances["flag"] == "")]  # an all-empty column reads as NaN
save_figure(campbell_diagram(modes, np.unique(np.round(resonances["frequency_hz"].to_numpy(float), 1)), max_frequency,
                             f"{machine_name}: Campbell diagram of the closed loop, model {last}"),
            snakemake.output.campbell_figure, snakemake.params.dpi)
log.info("campbell: %d modes at %d speeds up to %.0f Hz", len(modes), speeds.size, max_frequency)

# mode shapes of the levitated rotor (closed loop at standstill) up to 1.5 times the measured band
frequency, damping, shapes = levitated_modes(plants[last], count=4, max_frequency_hz=1.5 * band_top)
planar = np.zeros((2 * shapes.shape[0], shapes.shape[1]))
planar[0::2] = shapes  # mode_shapes draws the displacement rows of [u, theta]
rotor_machine = plants[last].machine
save_figure(mode_shapes(rotor_machine.rotor.node_positions_m, planar, frequency,
                        [b.actuator_position_m for b in rotor_machine.radial_bearings],
                        [b.sensor_position_m for b in rotor_machine.radial_bearings],
                        f"{machine_name}: levitated rotor, closed-loop modes at standstill (model {last})"),
            snakemake.output.modes_figure, snakemake.params.dpi)
log.info("levitated modes: %s Hz (damping %s)", np.round(frequency, 1), np.round(damping, 4))
