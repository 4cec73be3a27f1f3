"""Rule `update`: rotor model update (thesis ch. 5.2) from the fit stage's resonances -> updated machine, tables, figures."""

import numpy as np
import pandas as pd

from ambid.compare import model_channels
from ambid.frf import channel, radial_estimator
from ambid.io import read_parquet, read_yaml, rule_log, write_parquet, write_tsv, write_yaml
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.plots import bode_measured, save_figure, update_convergence, youngs_modulus
from ambid.update import (UpdateSettings, bias_at_values, comparison_rows, debiased_update, identifiability,
                          mode_shape_rows, update_channels, update_model, update_problem, updated_machine_config)
from ambid.variants import variant_config

log = rule_log(snakemake.log[0], "update")

machine_name, run = snakemake.wildcards.machine, snakemake.wildcards.run
settings = UpdateSettings.from_config(snakemake.params.settings, {**snakemake.params.machine_update,
                                                                  **({"modes": snakemake.params.run_modes}
                                                                     if snakemake.params.run_modes else {})})
machine_config = snakemake.params.machine_config
if "operating_point" in snakemake.input.keys():  # the bearings linearized where the variants have them
    operating_point = read_yaml(snakemake.input.operating_point)["bearings"]["radial"]["operating_point"]
    machine_config = variant_config(machine_config, [], operating_point, source=snakemake.input.machine)
machine = machine_from_config(machine_config, name=machine_name, source=snakemake.input.machine)
features, _ = read_parquet(snakemake.input.features, kind="fit_features")
problem = update_problem(machine, features, settings)
measured, variables, model = problem.measured, problem.variables, problem.model
log.info("%d measured features of %d channels, %d design variables, optimizer %s, %d starts", len(measured),
         len(set(zip(measured["output"], measured["input"]))), len(variables), settings.optimizer, settings.starts)
result = update_model(problem, settings)
frf, _ = read_parquet(snakemake.input.frf, kind="frf")
estimator = radial_estimator(frf)
if settings.estimator_bias:  # the fit stage's estimator on the updated model's own FRF: its error, taken off the features
    bias_at = bias_at_values(machine_config, problem, frf, snakemake.params.fit_settings, machine_name)
    problem, result = debiased_update(problem, result, settings, bias_at)
    shift = (problem.measured["frequency_bias_hz"] / problem.measured["frequency_std_hz"]).abs()
    log.info("estimator bias taken off %d of %d features; largest %.3g Hz, %.2g of its feature's standard deviations",
             int((problem.measured["frequency_bias_hz"] != 0).sum()), len(measured),
             problem.measured["frequency_bias_hz"].abs().max(), shift.max())
original_b = problem.objective(problem.start)
log.info("B(e) %.4g -> %.4g after %d evaluations; starts:\n%s", original_b, result.objective,
         result.evaluations, result.starts.to_string(index=False))
rows, correlation, summary = identifiability(problem, result.values, added_std=result.bias_spread)
log.info("identifiability: %d of %d variable directions determined; singular values %s; features chi2 %.4g for %d "
         "degrees of freedom (uncertainties scaled by %.3g)", summary["rank"], len(variables),
         np.array2string(summary["singular_values"], precision=3), summary["chi2"], summary["dof"], summary["std_scale"])

# tables: the thesis' feature comparison (Tables 5.2/5.3, 6.4/6.5) and the design variables
shape_rows, shapes = mode_shape_rows(problem, result.values)
log.info("mode shapes: %d modal constants, %d gain-free contrasts, chi2 %.3g at the result", shapes["constants"],
         shapes["contrasts"], shapes["chi2"])
write_tsv(pd.DataFrame(shape_rows, columns=["output", "input", "number", "frequency_hz", "modal_constant", "sigma",
                                            "model_constant", "contrast"]), snakemake.output.mode_shapes)
comparison = pd.DataFrame(comparison_rows(problem, problem.start, result.values))
write_parquet(comparison, snakemake.output.comparison, kind="update_comparison",
              units={"measured": "Hz or -", "measured_std": "Hz or -", "estimator_bias": "Hz or -", "original": "Hz or -",
                     "updated": "Hz or -", "absolute_error": "Hz or -", "number": "-", "error_pct": "%",
                     "original_error_pct": "%"},
              metadata={"machine": machine_name, "run": run})
write_tsv(comparison, snakemake.output.comparison_table)
structural = model.machine.rotor  # the moduli as configured, earlier element_stiffness effects included
table = []
spread = np.full(len(variables), np.nan) if result.bias_spread is None else result.bias_spread
for variable, value, row, moved in zip(variables, result.values, rows, spread):
    entry = {"variable": variable.name, "kind": variable.kind, "tag": variable.tag,
             "elements": " ".join(str(e + 1) for e in variable.elements), "start": variable.start, "updated": value,
             "lower": variable.lower, "upper": variable.upper, **row, "estimator_bias_spread": moved,
             "features_chi2_per_dof": summary["chi2"] / summary["dof"], "std_scale": summary["std_scale"]}
    if variable.kind == "stiffness":
        modulus = structural.elements[variable.elements[0]].material.youngs_modulus_pa
        entry.update(youngs_modulus_start_pa=modulus, youngs_modulus_updated_pa=modulus * value)
    table.append(entry)
table = pd.DataFrame(table)
write_tsv(table, snakemake.output.variables)
write_tsv(pd.DataFrame(correlation, index=table["variable"], columns=table["variable"]).reset_index(),
          snakemake.output.correlation)
write_parquet(result.history, snakemake.output.history, kind="update_history",
              units={"objective_b": "-", "sum_of_squares": "-", "start": "-", "evaluation": "-"},
              metadata={"machine": machine_name, "run": run, "optimizer": settings.optimizer})

# the updated machine: a config a user can read and reuse as a model
undetermined = [v.name for v, r in zip(variables, rows) if not r["determined"]]
updated_config = updated_machine_config(machine_config, variables, result.values)
updated_machine = machine_from_config(updated_config, name=machine_name, source=snakemake.output.machine)
header = (f"# {machine_name} updated by ambid (rule update, thesis ch. 5.2) from the features of run {run}.\n"
          f"# B(e) (eq. 5.35): {original_b:.4g} -> {result.objective:.4g}.  The 'effects' below carry the\n"
          f"# updated moduli and damping; use this file as a machine model (config.yaml: machines.<name>.model).\n")
if undetermined:
    header += f"# Not determined by the data (values arbitrary within their bounds): {', '.join(undetermined)}.\n"
write_yaml(updated_config, snakemake.output.machine, header)

# figures: Bode overlay (thesis Fig. 6.6 / 6.7), moduli (Fig. 5.5 / 6.8), convergence (Fig. 6.9)
plants = {"original model": Plant(machine), "updated model": Plant(updated_machine)}
channels = update_channels(settings.channels)
panels, overlays = [], []
for output, input_axis in [(o, i) for o, i in channels if o[1] == "X"]:
    frequency, values, std = channel(frf, estimator, output, input_axis)
    if frequency.size == 0:
        continue
    panels.append((f"{output}/{input_axis}", frequency, values, std))
    overlays.append({name: model_channels(plant, frequency, [(output, input_axis)])[(output, input_axis)]
                     for name, plant in plants.items()})
title = f"{machine_name} {run}"
save_figure(bode_measured(panels, f"{title}: measured, original and updated model", fits=overlays), snakemake.output.bode,
            snakemake.params.dpi)
stiffness = table[table["kind"] == "stiffness"].assign(label=lambda t: t["variable"])
save_figure(youngs_modulus(stiffness, f"{title}: Young's modulus of the design elements"), snakemake.output.modulus,
            snakemake.params.dpi)
chosen = int(result.starts.loc[result.starts["chosen"], "start"].iloc[0])
save_figure(update_convergence(result.history, chosen, f"{title}: {settings.optimizer} convergence"),
            snakemake.output.convergence, snakemake.params.dpi)
worst = comparison.groupby("quantity")["error_pct"].max()
log.info("largest error after the update: frequency %.4f %%, damping ratio %.2f %%", worst.get("frequency", np.nan),
         worst.get("damping ratio", np.nan))
