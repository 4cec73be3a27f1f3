"""Rule `fit`: parametric models of every selected FRF channel (thesis ch. 5.1) -> features, models, figures."""

import numpy as np
import pandas as pd

from ambid.channel_fit import (MAX_CHI2, FitError, feature_rows, fit_plant_channel, fit_verdict, known_response,
                               model_rows, select_channels)
from ambid.findings import Finding, write_findings
from ambid.fit import classify_poles, levy_thesis
from ambid.frf import channel, radial_estimator
from ambid.io import read_parquet, rule_log, write_parquet, write_tsv
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import bode_measured, save_figure, stabilization_diagram

log = rule_log(snakemake.log[0], "fit")

settings = snakemake.params.settings
machine = machine_from_config(snakemake.params.machine_config, name=snakemake.wildcards.machine, source=snakemake.input.machine)
plant = Plant(machine)
table, _ = read_parquet(snakemake.input.frf, kind="frf")
estimator = radial_estimator(table)
numerator_order, denominator_order = settings["thesis_orders"]
features, models, panels, fitted, diagrams, selected, findings = [], [], [], [], {}, {}, []
for output, input_axis in select_channels(settings["channels"]):
    frequency, measured, std = channel(table, estimator, output, input_axis)
    if frequency.size == 0:
        log.warning("%s <- %s: not in the FRF (axis not excited); skipped", output, input_axis)
        continue
    label = f"{output}/{input_axis}"
    known = known_response(plant, output, input_axis, frequency)
    try:
        result = fit_plant_channel(plant, frequency, measured, std, output, input_axis, settings, known=known)
    except FitError as error:  # this channel has no model: said where the fit is quoted, the others go on
        log.warning("%s: %s", label, error)
        findings.append(Finding("fit", "failure", "fit_failed", label, f"no fit: {error}"))
        continue
    log.info("%s: order %d, %d flexible mode(s) at %s Hz, delay %.1f us, chi2/dof %.2f, %d evaluations; dropped: %s",
             label, result.order, result.selected_hz.size, np.round(result.selected_hz, 2), result.model.delay_s * 1e6,
             result.cost, result.iterations, "; ".join(result.dropped) or "nothing")
    flag, verdict = fit_verdict(result, frequency, measured, known, label, settings.get("max_chi2", MAX_CHI2))
    findings += verdict
    features += feature_rows(result, output, input_axis, "output_error", flag, (frequency.min(), frequency.max()))
    models.append(model_rows(result, output, input_axis))
    reference = levy_thesis(frequency, measured, numerator_order, denominator_order)
    for row in classify_poles(reference.poles, reference.zeros, (frequency.min(), frequency.max())):
        if row["kind"] != "stable_rigid":
            features.append({"output": output, "input": input_axis, "estimator": "thesis", **row,
                             "frequency_std_hz": np.nan, "damping_std": np.nan, "modal_constant": np.nan,
                             "modal_constant_std": np.nan, "flag": ""})
    diagrams[label], selected[label] = result.stabilization, result.selected_hz
    panels.append((label, frequency, measured, std))
    fitted.append({"fit (output error)": result.model.frequency_response(frequency, known),
                   f"thesis {numerator_order}/{denominator_order}": reference.frequency_response(frequency)})
if not models:
    reasons = "; ".join(f"{f.subject}: {f.message}" for f in findings) or "not in the FRF"
    raise FitError(f"{snakemake.input.frf}: no channel of {settings['channels']!r} could be fitted ({reasons})")
features = pd.DataFrame(features)
write_parquet(features, snakemake.output.features, kind="fit_features",
              units={"frequency_hz": "Hz", "damping_ratio": "-", "frequency_std_hz": "Hz", "damping_std": "-", "number": "-",
                     "modal_constant": "m/(A s^2)", "modal_constant_std": "-"},
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
write_findings(findings, snakemake.output.findings)
log.info("fit written: %d channels, %d feature rows, %d finding(s)", len(models), len(features), len(findings))
