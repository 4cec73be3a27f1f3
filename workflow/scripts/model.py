"""Rule `model`: one model variant of a machine -> mode table, plant FRF, stability, figures."""

import pandas as pd

from ambid.io import frf_frame, read_yaml, rule_log, write_parquet, write_tsv
from ambid.loop import check_stable, stability_summary
from ambid.machine import AXIAL_AXIS, RADIAL_AXES, machine_from_config
from ambid.modes import mode_table
from ambid.plant import Plant
from ambid.plots import bode_matrix, bode_siso, mode_shapes, save_figure

log = rule_log(snakemake.log[0], "model")

machine = machine_from_config(read_yaml(snakemake.input.machine), name=snakemake.wildcards.machine,
                              source=snakemake.input.machine)
plant = Plant(machine)
log.info("machine %s: %d elements, %.3f kg, %d retained modes", machine.name, machine.rotor.n_elements,
         machine.rotor.mass_kg, machine.retained_modes)

radial_hz = machine.radial_grid.frequency_hz
axial_hz = machine.axial_grid.frequency_hz
radial = plant.radial_frequency_response(radial_hz)
axial = plant.axial_frequency_response(axial_hz)[:, None, None]
frame = pd.concat(
    [frf_frame(radial_hz, radial, RADIAL_AXES, RADIAL_AXES), frf_frame(axial_hz, axial, [AXIAL_AXIS], [AXIAL_AXIS])],
    ignore_index=True,
)
write_parquet(
    frame,
    snakemake.output.frf,
    units={"frequency_hz": "Hz", "re": "m/A", "im": "m/A"},
    kind="plant_frf",
    metadata={
        "machine": machine.name,
        "variant": snakemake.wildcards.variant,
        "effects": [effect.to_config() for effect in machine.effects],
        "input": "control current [A]",
        "output": "sensor position [m]",
    },
)
modes = mode_table(plant)
write_tsv(modes, snakemake.output.modes)
check_stable(plant, f"{snakemake.input.machine}: model variant {snakemake.wildcards.variant!r}")
stability = stability_summary(plant)
for row in stability:
    log.info("%s: closed-loop spectral radius %.6f (%s), sensitivity peak %.1f dB at %.0f Hz (ISO 14839-3 zone %s)",
             row["axis"], row["spectral_radius"], row["verdict"], row["sensitivity_peak_db"], row["sensitivity_peak_hz"],
             row["iso_14839_zone"] or "none")
write_tsv(stability, snakemake.output.stability)

title = f"{machine.name} ({snakemake.wildcards.variant}): open-loop plant"
dpi = snakemake.params.dpi
save_figure(bode_matrix(radial_hz, radial, RADIAL_AXES, RADIAL_AXES, title), snakemake.output.bode, dpi)
save_figure(bode_siso(axial_hz, axial[:, 0, 0], f"{title}, axial Z"), snakemake.output.axial_bode, dpi)
flexible = plant.modes.frequency_hz > 0.5  # the two rigid-body modes are not drawn
bearings = machine.radial_bearings
save_figure(
    mode_shapes(
        machine.rotor.node_positions_m,
        plant.modes.shapes[:, flexible][:, :4],
        plant.modes.frequency_hz[flexible][:4],
        [b.actuator_position_m for b in bearings],
        [b.sensor_position_m for b in bearings],
        f"{machine.name}: free-free bending modes",
    ),
    snakemake.output.mode_shapes,
    dpi,
)
log.info("done: %d modes in the table, FRF on %d + %d frequencies", len(modes), radial_hz.size, axial_hz.size)
