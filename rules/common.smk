# Configuration validation, machine models, input functions and the library digest.
import hashlib
from pathlib import Path

import yaml
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate

from ambid.calibration import calibration_settings_from_config
from ambid.errors import ConfigError
from ambid.excitation import settings_from_config
from ambid.machine import machine_from_config
from ambid.rig import rig_from_config

validate(config, schema="../workflow/schemas/config.schema.yaml")

MODEL_VARIANTS = ["nominal"]


def load_machine_config(name):
    """Read and validate one machine model; raise naming the file and key at fault."""
    path = config["machines"][name]["model"]
    try:
        with open(path) as handle:
            machine_config = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f"machines.{name}.model", f"cannot read {path}: {error}") from None
    if not isinstance(machine_config, dict):
        raise ConfigError(f"machines.{name}.model", f"{path} does not hold a mapping")
    try:
        validate(machine_config, schema="../workflow/schemas/machine.schema.yaml")
    except WorkflowError as error:
        raise ConfigError(f"machines.{name}.model", f"{path} does not match the machine schema: {error}") from None
    machine_from_config(machine_config, name=name, source=path)  # cross-reference checks
    return machine_config


MACHINE_CONFIGS = {name: load_machine_config(name) for name in config["machines"]}


def load_rig_config(name):
    """Read and validate a machine's virtual rig truth (passed only to acquisition rules)."""
    path = config["machines"][name].get("rig")
    if path is None:
        raise ConfigError(f"machines.{name}.rig", "runs with source 'rig' need a rig file")
    try:
        with open(path) as handle:
            rig_config = yaml.safe_load(handle)
        validate(rig_config, schema="../workflow/schemas/rig.schema.yaml")
    except (OSError, yaml.YAMLError, WorkflowError) as error:
        raise ConfigError(f"machines.{name}.rig", f"{path}: {error}") from None
    if rig_config["machine"] != name:
        raise ConfigError(f"machines.{name}.rig", f"{path} is the rig of machine {rig_config['machine']!r}")
    rig_from_config(rig_config, MACHINE_CONFIGS[name], source=path)  # cross-reference checks
    return rig_config


RUNS = {
    (machine, run): spec
    for machine, entry in config["machines"].items()
    for run, spec in (entry.get("runs") or {}).items()
}
RIG_CONFIGS = {
    machine: load_rig_config(machine) for machine in {m for (m, _), spec in RUNS.items() if spec["source"] == "rig"}
}
IDENTIFICATION_SETTINGS = settings_from_config(config["identification"])
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


def rig_file(wildcards):
    return config["machines"][wildcards.machine]["rig"]


def rig_config(wildcards):
    return RIG_CONFIGS[wildcards.machine]


def run_seed(wildcards):
    return RUNS[(wildcards.machine, wildcards.run)].get("seed", 0)


def thesis_m_runs():
    """Runs whose raw log is a user's thesis-style .m file (converted by rule import_thesis_m)."""
    return [run for (_, run), spec in RUNS.items() if spec["source"] == "data" and spec.get("format") == "m"]


def runs_of(kind, source=None):
    return [(m, r) for (m, r), spec in RUNS.items() if spec["kind"] == kind and source in (None, spec["source"])]


CALIBRATION_OUTPUTS = [
    "offsets.tsv",
    "pairs.tsv",
    "repeatability.tsv",
    "magnetic_center.tsv",
    "stiffness.tsv",
    "operating_point.yaml",
    "figures/convergence.png",
]


UPDATE_OUTPUTS = [
    "comparison.parquet",
    "comparison.tsv",
    "variables.tsv",
    "correlation.tsv",
    "history.parquet",
    "machine.yaml",
    "figures/bode_update.png",
    "figures/youngs_modulus.png",
    "figures/convergence.png",
]


def all_outputs():
    acquired = [
        f"data/{machine}/{run}/identification.{suffix}"
        for machine, run in runs_of("identification", "rig")
        for suffix in ("parquet", "m")
    ]
    calibration = [
        f"results/{machine}/calibration/{run}/{name}"
        for machine, run in runs_of("calibration")
        for name in CALIBRATION_OUTPUTS
    ]
    sensitivity = [f"results/{machine}/calibration/{run}/sensitivity.tsv" for machine, run in runs_of("calibration", "rig")]
    frfs = [
        f"results/{machine}/frf/{run}/{name}"
        for machine, run in runs_of("identification")
        for name in ("frf.parquet", "frf.uff", "figures/radial_siso.png", "figures/radial_mimo.png", "figures/axial.png")
    ]
    fits = [
        f"results/{machine}/fit/{run}/{name}"
        for machine, run in runs_of("identification")
        for name in ("features.parquet", "features.tsv", "models.parquet", "figures/bode_fit.png", "figures/stabilization.png")
    ]
    updates = [
        f"results/{machine}/update/{run}/{name}"
        for machine, run in runs_of("identification")
        if config["machines"][machine].get("update")
        for name in UPDATE_OUTPUTS
    ]
    return acquired + calibration + sensitivity + frfs + fits + updates + expand(
        [
            "results/{machine}/model/{variant}/modes.tsv",
            "results/{machine}/model/{variant}/plant_frf.parquet",
            "results/{machine}/model/{variant}/stability.tsv",
            "results/{machine}/model/{variant}/figures/plant_bode.png",
            "results/{machine}/model/{variant}/figures/axial_bode.png",
            "results/{machine}/model/{variant}/figures/mode_shapes.png",
        ],
        machine=MACHINE_CONFIGS,
        variant=MODEL_VARIANTS,
    )
