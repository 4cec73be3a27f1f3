"""Rule `variant`: the machine config of one model variant (operating point, added effects, updates)."""

from ambid.io import read_yaml, rule_log, write_yaml
from ambid.loop import check_stable
from ambid.machine import machine_from_config
from ambid.plant import Plant
from ambid.variants import variant_config

log = rule_log(snakemake.log[0], "variant")

operating_point = None
if "operating_point" in snakemake.input.keys():
    operating_point = read_yaml(snakemake.input.operating_point)["bearings"]["radial"]["operating_point"]
updates = iter(snakemake.input.updates)
steps = []
for step in snakemake.params.steps:
    update_effects = read_yaml(next(updates)).get("effects", []) if step["update"] else None
    steps.append({"effects": step["effects"], "update_effects": update_effects})
    log.info("step %s: %d effects added%s", step["name"], len(step["effects"]),
             f", stiffness and damping of update {step['update']}" if step["update"] else "")
config = variant_config(snakemake.params.machine_config, steps, operating_point, source=snakemake.output.machine)
# an unstable variant stops here, before its plant, comparison and diagnosis (nothing downstream is meaningful)
check_stable(Plant(machine_from_config(config, name=snakemake.wildcards.machine, source=snakemake.output.machine)),
             f"{snakemake.output.machine}: model variant {snakemake.wildcards.variant!r}")
chain = " -> ".join(["nominal"] + [step["name"] for step in snakemake.params.steps])
header = (f"# {snakemake.wildcards.machine}, model variant {snakemake.wildcards.variant} ({chain}), written by ambid rule variant.\n"
          + (f"# Bearings linearized at the operating point of {snakemake.input.operating_point}.\n" if operating_point else ""))
write_yaml(config, snakemake.output.machine, header)
log.info("variant %s: %d effects: %s", snakemake.wildcards.variant, len(config["effects"]),
         ", ".join(e["name"] for e in config["effects"]) or "none")
