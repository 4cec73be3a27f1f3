# Configuration validation, machine models, input functions and the library digest.
import hashlib
from pathlib import Path

import jsonschema
import yaml
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate

from ambid.calibration import calibration_settings_from_config
from ambid.channel_fit import max_fit_modes
from ambid.errors import ConfigError
from ambid.excitation import settings_from_config
from ambid.io import file_digest, read_yaml
from ambid.kernels import pin_cpu_kernels, pin_job_threads
from ambid.multisine import multisine_settings_from_config
from ambid.machine import machine_from_config
from ambid.effects import effect_from_config
from ambid.rig import rig_from_config
from ambid.update import UpdateSettings
from ambid.variants import NOMINAL, variant_chain

# every job's numpy and OpenBLAS on the AVX2 kernels: the same bytes on any x86-64 CPU; one BLAS thread per job, as
# its rule declares (ambid.kernels)
pin_cpu_kernels()
pin_job_threads()


def check_schema(instance, schema, source):
    """Validate against a JSON schema (filling its defaults); raise one ConfigError naming the file and key at fault."""
    try:
        validate(instance, schema=f"../workflow/schemas/{schema}")
    except WorkflowError:
        with open(Path(workflow.basedir, "workflow", "schemas", schema)) as handle:
            validator = jsonschema.Draft202012Validator(yaml.safe_load(handle))
        error = jsonschema.exceptions.best_match(validator.iter_errors(instance))
        key = "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in error.absolute_path).lstrip(".")
        raise ConfigError(key or "(top level)", error.message, source=source) from None


CONFIG_SOURCE = ", ".join(str(path) for path in workflow.configfiles) or "config"
for _path in workflow.configfiles:  # Snakemake's loader keeps the last of duplicate keys: refuse them
    read_yaml(_path)
check_schema(config, "config.schema.yaml", CONFIG_SOURCE)


def read_machine_file(path, key, name):
    """Read and validate a machine file; raise naming the file and the config key that points to it."""
    machine_config = read_yaml(path, key)  # duplicate keys refused
    check_schema(machine_config, "machine.schema.yaml", path)
    machine_from_config(machine_config, name=name, source=path)  # cross-reference checks
    return machine_config


MACHINE_CONFIGS = {
    name: read_machine_file(entry["model"], f"machines.{name}.model", name)
    for name, entry in config["machines"].items()
}


def load_rig_config(name):
    """Read and validate a machine's virtual rig truth and its as-built machine (acquisition rules only)."""
    path = config["machines"][name].get("rig")
    if path is None:
        raise ConfigError(f"machines.{name}.rig", "runs with source 'rig' need a rig file")
    rig_config = read_yaml(path, f"machines.{name}.rig")  # duplicate keys refused
    check_schema(rig_config, "rig.schema.yaml", path)
    if rig_config["machine"] != name:
        raise ConfigError(f"machines.{name}.rig", f"{path} is the rig of machine {rig_config['machine']!r}")
    as_built = read_machine_file(rig_config["as_built"], f"{path}: as_built", name)
    rig_from_config(rig_config, as_built, source=path)  # cross-reference checks
    return rig_config, as_built


RUNS = {
    (machine, run): spec
    for machine, entry in config["machines"].items()
    for run, spec in (entry.get("runs") or {}).items()
}
RIG_CONFIGS = {
    machine: load_rig_config(machine) for machine in {m for (m, _), spec in RUNS.items() if spec["source"] == "rig"}
}  # machine -> (rig config, as-built machine config)


def variants_of(machine):
    """Model variants of a machine: nominal first, then the configured ones."""
    return [NOMINAL] + list(config["machines"][machine].get("variants") or {})


def check_variants(machine):
    """Every variant's chain, effects and update run are consistent; raise naming the key at fault."""
    entry = config["machines"][machine]
    variants = entry.get("variants") or {}
    nominal = machine_from_config(MACHINE_CONFIGS[machine], name=machine)
    for name in variants:
        for step, spec in variant_chain(variants, name, f"machines.{machine}.variants"):
            path = f"machines.{machine}.variants.{step}"
            for i, effect in enumerate(spec.get("effects") or ()):
                try:
                    effect_from_config(effect, f"effects[{i}]", nominal)
                except ConfigError as error:
                    raise error.within(path) from None
            run = spec.get("update")
            if run is not None and (
                RUNS.get((machine, run), {}).get("kind") != "identification" or not entry.get("update")
            ):
                raise ConfigError(
                    f"{path}.update", f"needs an identification run of {machine} and machines.{machine}.update"
                )
    cal = entry.get("operating_point")
    if cal is not None and RUNS.get((machine, cal), {}).get("kind") != "calibration":
        raise ConfigError(f"machines.{machine}.operating_point", f"{cal!r} is not a calibration run of {machine}")
    for run, spec in (entry.get("runs") or {}).items():
        if spec.get("method") == "multisine" and spec.get("format") == "m":
            raise ConfigError(
                f"machines.{machine}.runs.{run}.format", "a multisine run's log is multisine.parquet, not .m"
            )
        cal = spec.get("calibration")
        if cal is not None and RUNS.get((machine, cal), {}).get("kind") != "calibration":
            raise ConfigError(
                f"machines.{machine}.runs.{run}.calibration", f"{cal!r} is not a calibration run of {machine}"
            )


for _machine in config["machines"]:
    check_variants(_machine)


def check_stage_settings():
    """Checks of the stage settings that need no data, so that a bad value stops the workflow before any job."""
    fit_modes = max_fit_modes(config["fit"])
    update_settings = {}
    for name, entry in config["machines"].items():
        if entry.get("update"):
            settings = UpdateSettings.from_config(config["update"], entry["update"])
            settings.check_against(machine_from_config(MACHINE_CONFIGS[name], name=name), f"machines.{name}.update")
            if settings.modes > fit_modes:
                raise ConfigError(
                    "update.modes",
                    f"{settings.modes} flexible modes, but the fit gives a channel "
                    f"{fit_modes} at most (fit.modes / fit.orders)",
                )
    bands = config["compare"]["bands_hz"] or []  # null: bands from the measured grid
    if any(b <= a for a, b in zip(bands, bands[1:])):
        raise ConfigError("compare.bands_hz", f"lower band edges must increase strictly, got {bands}")


try:
    check_stage_settings()
except ConfigError as error:
    raise error.within(source=error.source or CONFIG_SOURCE) from None
MODEL_VARIANTS = sorted({v for m in config["machines"] for v in variants_of(m)})
IDENTIFICATION_SETTINGS = settings_from_config(config["identification"])
MULTISINE_SETTINGS = multisine_settings_from_config(config["multisine"])
CALIBRATION_SETTINGS = calibration_settings_from_config(config["calibration"])


wildcard_constraints:
    machine="|".join(MACHINE_CONFIGS),
    variant="|".join(MODEL_VARIANTS),
    run="|".join(sorted({run for _, run in RUNS})) or "no_runs",


def library_digest():
    """SHA-256 of the ambid sources: a param, so rules rerun when the library changes."""
    digest = hashlib.sha256()
    for source in sorted((Path(workflow.basedir) / "workflow" / "ambid").rglob("*.py")):
        digest.update(source.name.encode())
        digest.update(source.read_bytes())
    return digest.hexdigest()[:16]


LIBRARY_DIGEST = library_digest()


def machine_model_file(wildcards):
    return config["machines"][wildcards.machine]["model"]


def machine_config(wildcards):
    return MACHINE_CONFIGS[wildcards.machine]


def rig_files(wildcards):
    """The rig's truth and its as-built machine file (inputs of the acquisition rules)."""
    return {
        "rig": config["machines"][wildcards.machine]["rig"],
        "as_built": RIG_CONFIGS[wildcards.machine][0]["as_built"],
    }


def rig_config(wildcards):
    return RIG_CONFIGS[wildcards.machine][0]


def as_built_config(wildcards):
    return RIG_CONFIGS[wildcards.machine][1]


def run_seed(wildcards):
    return RUNS[(wildcards.machine, wildcards.run)].get("seed", 0)


def variant_steps(wildcards):
    """The variant's chain as the variant rule's param: name, effects and update run of each step."""
    variants = config["machines"][wildcards.machine].get("variants") or {}
    return [
        {"name": name, "effects": spec.get("effects") or [], "update": spec.get("update")}
        for name, spec in variant_chain(variants, wildcards.variant, f"machines.{wildcards.machine}.variants")
    ]


def diagnose_priority(wildcards):
    """Scheduling: diagnoses before the short jobs, and first those of variants carrying an update.

    A diagnosis is the workflow's longest kind of job; one of a variant with an update also refits the update's
    moduli (hs_eden_like ms01: 27 s against 10 s), so it starts first rather than leaving one core idle at the end.
    """
    return 1 + any(step["update"] for step in variant_steps(wildcards))


def operating_point_file(machine):
    """The operating point of the calibration a machine's model is linearized at (its ``operating_point:`` run)."""
    return f"results/{machine}/calibration/{config['machines'][machine]['operating_point']}/operating_point.yaml"


def update_inputs(wildcards):
    """The run's features and FRF, the machine file and the calibration's operating point (the variants' own)."""
    entry = config["machines"][wildcards.machine]
    inputs = {
        "features": f"results/{wildcards.machine}/fit/{wildcards.run}/features.parquet",
        "frf": f"results/{wildcards.machine}/frf/{wildcards.run}/frf.parquet",
        "machine": machine_model_file(wildcards),
    }
    if entry.get("operating_point"):
        inputs["operating_point"] = operating_point_file(wildcards.machine)
    return inputs


def variant_inputs(wildcards):
    """Machine file, the calibration's operating point and the updates the variant takes."""
    entry = config["machines"][wildcards.machine]
    inputs = {"machine": machine_model_file(wildcards)}
    if entry.get("operating_point"):
        inputs["operating_point"] = operating_point_file(wildcards.machine)
    inputs["updates"] = [
        f"results/{wildcards.machine}/update/{step['update']}/machine.yaml"
        for step in variant_steps(wildcards)
        if step["update"]
    ]
    return inputs


def diagnose_inputs(wildcards):
    """The run's FRF and the variant's machine file; and the run's own update where the variant takes another run's.

    The joint refit of the variant's own parameters also descends from the run's own update (`ambid.diagnose.joint_refit`,
    ``alternatives``): an update from a run of another band leaves the moduli that band did not determine anywhere.
    """
    inputs = {
        "frf": f"results/{wildcards.machine}/frf/{wildcards.run}/frf.parquet",
        "machine": f"results/{wildcards.machine}/model/{wildcards.variant}/machine.yaml",
    }
    taken = {step["update"] for step in variant_steps(wildcards) if step["update"]}
    if taken - {wildcards.run} and config["machines"][wildcards.machine].get("update"):
        inputs["run_update"] = f"results/{wildcards.machine}/update/{wildcards.run}/machine.yaml"
    return inputs


def identification_center(wildcards):
    """The calibration log whose magnetic center an identification run is centred on (its ``calibration`` run).

    The bench computes the center from the log as it runs, with the drawing's bearing parameters, so the
    acquisition does not wait for (or depend on) the model-side ``calibrate`` rule.
    """
    cal = RUNS[(wildcards.machine, wildcards.run)].get("calibration")
    return {"calibration_log": f"data/{wildcards.machine}/{cal}/calibration.parquet"} if cal else {}


#: the user's file in data/<machine>/<run>/ by run format, unless the run names its own (key `file`)
USER_FILES = {"m": "identification.m", "table": "identification.csv", "mat": "identification.mat", "uff": "frf.uff"}


def imported_runs():
    """Runs whose raw log is a user's file in another format (converted by rule import_log)."""
    return [
        run
        for (_, run), spec in RUNS.items()
        if spec["source"] == "data" and spec.get("format") in ("m", "table", "mat")
    ]


def user_log_file(wildcards):
    spec = RUNS[(wildcards.machine, wildcards.run)]
    return f"data/{wildcards.machine}/{wildcards.run}/{spec.get('file') or USER_FILES[spec['format']]}"


def reader_units(wildcards):
    spec = RUNS[(wildcards.machine, wildcards.run)]
    return {key: spec[key] for key in ("position_unit", "current_unit") if key in spec}


def uff_options(wildcards):
    """Reader options of a run with format uff (empty for the others)."""
    spec = RUNS[(wildcards.machine, wildcards.run)]
    return {
        key: spec[key]
        for key in ("estimator", "position_unit", "current_unit")
        if key in spec and spec["format"] == "uff"
    }


def frf_input(wildcards):
    """The FRF stage's input: the canonical log (stepped sine or multisine), or a run's UFF58 FRFs (format uff)."""
    if RUNS[(wildcards.machine, wildcards.run)].get("format") == "uff":
        return {"uff": user_log_file(wildcards)}
    return {"log": identification_log(wildcards.machine, wildcards.run)}


def run_method(wildcards):
    """The identification method of a run: ``stepped_sine`` or ``multisine``."""
    return RUNS[(wildcards.machine, wildcards.run)].get("method", "stepped_sine")


def log_source(wildcards):
    """A user's log of a run and its content digest (a param, so that a changed log reruns what depends on it
    whatever its modification time: cp -p, rsync -a, tar); empty for logs the workflow acquires."""
    spec = RUNS[(wildcards.machine, wildcards.run)]
    if spec["source"] != "data":
        return {}
    if spec["kind"] != "identification":
        path = f"data/{wildcards.machine}/{wildcards.run}/calibration.parquet"
    elif spec.get("format", "parquet") == "parquet":
        path = f"data/{wildcards.machine}/{wildcards.run}/identification.parquet"
    else:
        path = user_log_file(wildcards)
    return {"file": path, "digest": file_digest(path)}


for (_machine, _run), _spec in RUNS.items():
    if _spec.get("file") in ("identification.parquet",) and _spec.get("format") != "parquet":
        raise ConfigError(
            f"machines.{_machine}.runs.{_run}.file",
            "identification.parquet is the canonical log the "
            "import writes; name your file otherwise (e.g. identification.csv)",
        )


def runs_of(kind, source=None):
    return [(m, r) for (m, r), spec in RUNS.items() if spec["kind"] == kind and source in (None, spec["source"])]


def identification_runs(method, source=None):
    """Identification runs of one method (``stepped_sine``, ``multisine``), optionally of one source."""
    return [
        (m, r) for m, r in runs_of("identification", source) if RUNS[(m, r)].get("method", "stepped_sine") == method
    ]


def identification_log(machine, run):
    """The raw log of an identification run: ``multisine.parquet`` or ``identification.parquet``."""
    name = "multisine" if RUNS[(machine, run)].get("method", "stepped_sine") == "multisine" else "identification"
    return f"data/{machine}/{run}/{name}.parquet"


CALIBRATION_OUTPUTS = [
    "offsets.tsv",
    "pairs.tsv",
    "repeatability.tsv",
    "magnetic_center.tsv",
    "stiffness.tsv",
    "operating_point.yaml",
    "figures/convergence.png",
]


MODEL_OUTPUTS = [
    "machine.yaml",
    "modes.tsv",
    "plant_frf.parquet",
    "stability.tsv",
    "figures/plant_bode.png",
    "figures/axial_bode.png",
    "figures/mode_shapes.png",
]
FRF_OUTPUTS = [
    "plausibility.tsv",
    "frf.parquet",
    "floor.tsv",
    "findings.tsv",
    "frf.uff",
    "figures/radial_siso.png",
    "figures/radial_mimo.png",
    "figures/axial.png",
]
MULTISINE_FRF_OUTPUTS = [
    "plausibility.tsv",
    "frf.parquet",
    "frf.uff",
    "distortion.tsv",
    "figures/radial_mimo.png",
    "figures/axial.png",
    "figures/distortion.png",
]
METHODS_OUTPUTS = ["comparison.tsv", "figures/methods.png"]
FIT_OUTPUTS = [
    "features.parquet",
    "features.tsv",
    "findings.tsv",
    "models.parquet",
    "figures/bode_fit.png",
    "figures/stabilization.png",
]
EXPORT_OUTPUTS = ["frf.csv", "frf.mat", "models.csv", "models.mat"]
COMPARE_OUTPUTS = ["errors.parquet", "summary.tsv", "findings.tsv", "figures/bode_compare.png", "figures/error_map.png"]
DIAGNOSE_OUTPUTS = [
    "candidates.tsv",
    "joint.tsv",
    "cells.tsv",
    "findings.tsv",
    "verdict.tsv",
    "diagnosis.md",
    "figures/fingerprint.png",
]
LEDGER_OUTPUTS = ["ledger.parquet", "ledger.tsv", "figures/ledger.png", "figures/excess_maps.png"]


UPDATE_OUTPUTS = [
    "comparison.parquet",
    "comparison.tsv",
    "variables.tsv",
    "correlation.tsv",
    "mode_shapes.tsv",
    "history.parquet",
    "machine.yaml",
    "figures/bode_update.png",
    "figures/youngs_modulus.png",
    "figures/convergence.png",
]


def machine_outputs(machine):
    """Every result of one machine but its report: acquired logs, calibration, FRF, fit, update, models, diagnosis."""
    identification = runs_of_machine(machine)
    calibration = runs_of_machine(machine, "calibration")
    rig_runs = {run for m, run in runs_of("identification", "rig") + runs_of("calibration", "rig") if m == machine}
    multisine = {run for m, run in identification_runs("multisine") if m == machine}
    outputs = [
        f"data/{machine}/{run}/identification.{suffix}"
        for run in identification
        if run in rig_runs and run not in multisine
        for suffix in ("parquet", "m")
    ]
    outputs += [identification_log(machine, run) for run in identification if run in rig_runs and run in multisine]
    outputs += [f"results/{machine}/calibration/{run}/{name}" for run in calibration for name in CALIBRATION_OUTPUTS]
    outputs += [f"results/{machine}/calibration/{run}/sensitivity.tsv" for run in calibration if run in rig_runs]
    outputs += [
        f"results/{machine}/frf/{run}/{name}"
        for run in identification
        for name in (MULTISINE_FRF_OUTPUTS if run in multisine else FRF_OUTPUTS)
    ]
    outputs += [
        f"results/{machine}/{stage}/{run}/{name}"
        for run in identification
        for stage, names in (("fit", FIT_OUTPUTS), ("export", EXPORT_OUTPUTS))
        for name in names
    ]
    if multisine:
        outputs += [f"results/{machine}/methods/{name}" for name in METHODS_OUTPUTS]
    if config["machines"][machine].get("update"):
        outputs += [f"results/{machine}/update/{run}/{name}" for run in identification for name in UPDATE_OUTPUTS]
    outputs += [
        f"results/{machine}/model/{variant}/{name}" for variant in variants_of(machine) for name in MODEL_OUTPUTS
    ]
    outputs += [
        f"results/{machine}/{stage}/{run}/{variant}/{name}"
        for run in identification
        for variant in variants_of(machine)
        for stage, names in (("compare", COMPARE_OUTPUTS), ("diagnose", DIAGNOSE_OUTPUTS))
        for name in names
    ]
    if identification:
        outputs += [f"results/{machine}/ledger/{name}" for name in LEDGER_OUTPUTS]
    outputs += [
        f"results/{machine}/commissioning/{run}/{name}"
        for run in commissioning_runs(machine)
        for name in COMMISSIONING_OUTPUTS
    ]
    return outputs


COMMISSIONING_OUTPUTS = [
    "sensitivity.tsv",
    "campbell.tsv",
    "figures/sensitivity.png",
    "figures/campbell.png",
    "figures/levitated_modes.png",
]


def commissioning_runs(machine):
    """Identification runs with a stepped-sine log (its U2 over the known excitation is the measured sensitivity)."""
    multisine = {run for m, run in identification_runs("multisine") if m == machine}
    return [
        run for run in runs_of_machine(machine) if run not in multisine and RUNS[(machine, run)].get("format") != "uff"
    ]


def commissioning_variants(machine):
    """The model variants drawn beside the measured sensitivity: nominal and the last configured one."""
    variants = variants_of(machine)
    return list(dict.fromkeys([variants[0], variants[-1]]))


def all_outputs():
    """The default target: each machine's report (which needs all of its results)."""
    return [f"results/{machine}/report.html" for machine in MACHINE_CONFIGS]


def runs_of_machine(machine, kind="identification"):
    return [run for m, run in runs_of(kind) if m == machine]
