"""Rule `fit`: parametric models of every selected FRF channel (thesis ch. 5.1) -> features, models, figures."""

import numpy as np
import pandas as pd

from ambid.channel_fit import (FitError, feature_rows, fit_channel, known_response, model_rows, rigid_pole_hz,
                               select_channels)
from ambid.fit import classify_poles, levy_thesis
from ambid.frf import channel
from ambid.io import read_parquet, rule_log, write_parquet, write_tsv
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import bode_measured, save_figure, stabilization_diagram

log = rule_log(snakemake.log[0], "fit")

settings = snakemake.params.settings
machine = machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine, source=snakemake.input.machine)
plant = Plant(machine)
table, _ = read_parquet(snakemake.input.frf, kind="frf")
estimator = "mimo" if (table["estimator"] == "mimo").any() else "siso"
hint = rigid_pole_hz(plant)
numerator_order, denominator_order = settings["thesis_orders"]
features, models, panels, fitted, diagrams, selected = [], [], [], [], {}, {}
for output, input_axis in select_channels(settings["channels"]):
    frequency, measured, std = channel(table, estimator, output, input_axis)
    if frequency.size == 0:
        log.warning("%s <- %s: not in the FRF (axis not excited); skipped", output, input_axis)
        continue
    label = f"{output}/{input_axis}"
    known = known_response(plant, output, input_axis, frequency)
    try:
        result = fit_channel(frequency, measured, std=std, known=known, modes=settings["modes"], orders=settings["orders"],
                             lowpass=settings["lowpass"], delay=settings["delay"], rigid_hint_hz=hint)
    except FitError as error:
        raise FitError(f"{snakemake.input.frf}: channel {label}: {error}") from None
    log.info("%s: order %d, %d flexible mode(s) at %s Hz, delay %.1f us, chi2/dof %.2f, %d evaluations; dropped: %s",
             label, result.order, result.selected_hz.size, np.round(result.selected_hz, 2), result.model.delay_s * 1e6,
             result.cost, result.iterations, "; ".join(result.dropped) or "nothing")
    features += feature_rows(result, output, input_axis, "output_error")
    models.append(model_rows(result, output, input_axis))
    reference = levy_thesis(frequency, measured, numerator_order, denominator_order)
    for row in classify_poles(reference.poles, reference.zeros, (frequency.min(), frequency.max())):
        if row["kind"] != "stable_rigid":
            features.append({"output": output, "input": input_axis, "estimator": "thesis", **row,
                             "frequency_std_hz": np.nan, "damping_std": np.nan, "modal_constant": np.nan})
    diagrams[label], selected[label] = result.stabilization, result.selected_hz
    panels.append((label, frequency, measured, std))
    fitted.append({"fit (output error)": result.model.frequency_response(frequency, known),
                   f"thesis {numerator_order}/{denominator_order}": reference.frequency_response(frequency)})
if not models:
    raise FitError(f"{snakemake.input.frf}: no channel of {settings['channels']!r} was measured")
features = pd.DataFrame(features)
write_parquet(features, snakemake.output.features, kind="fit_features",
              units={"frequency_hz": "Hz", "damping_ratio": "-", "frequency_std_hz": "Hz", "damping_std": "-", "number": "-",
                     "modal_constant": "m/(A s^2)"},
              metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run, "estimator": estimator})
write_tsv(features, snakemake.output.table)
write_parquet(pd.DataFrame(models), snakemake.output.models, kind="fit_models",
              units={"gain": "m/A (rad/s)^k", "residual_s2": "s^2", "lowpass_rad_s": "rad/s", "delay_s": "s", "order": "-",
                     "cost": "-"},
              metadata={"machine": snakemake.wildcards.machine, "run": snakemake.wildcards.run})
title = f"{snakemake.wildcards.machine} {snakemake.wildcards.run} ({estimator.upper()} FRF)"
save_figure(bode_measured(panels, f"{title}: measured and fitted", fits=fitted), snakemake.output.bode, snakemake.params.dpi)
band = (min(p[1].min() for p in panels), max(p[1].max() for p in panels))
save_figure(stabilization_diagram(diagrams, selected, band, f"{title}: stabilization diagrams"), snakemake.output.stabilization,
            snakemake.params.dpi)
log.info("fit written: %d channels, %d feature rows", len(models), len(features))
