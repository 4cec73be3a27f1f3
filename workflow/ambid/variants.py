"""Model variants: a machine, its effects and its updated parameters, as config.

A variant is the machine file as written (``nominal``) or a chain of steps on
top of it, each adding ``effects:`` entries (what the diagnosis recommends) or
taking the stiffness and damping of a model update::

    variants:
      amplifier: {effects: [{name: amplifier_lowpass, parameters: {cutoff_hz: 1775}}]}
      updated: {base: amplifier, update: ident01}

Every variant linearizes the bearings at the operating point the magnetic
center calibration found, when the machine names one (``operating_point:
cal01``).  Adding an effect is a config edit; Snakemake reruns only what
depends on that variant.
"""

import copy

from .errors import ConfigError
from .machine import machine_from_config

__all__ = ["NOMINAL", "UPDATED_EFFECTS", "variant_chain", "variant_config"]

NOMINAL = "nominal"
#: The effects a model update sets (``ambid.update.updated_machine_config``).
UPDATED_EFFECTS = ("element_stiffness", "modal_damping")


def variant_chain(variants, name, path="variants"):
    """The steps from nominal to variant ``name``, nominal's child first: list of (name, spec).

    Raises
    ------
    ConfigError
        For an unknown variant or base, or bases that form a cycle.
    """
    chain, seen = [], set()
    while name != NOMINAL:
        if name in seen:
            raise ConfigError(f"{path}.{name}.base", "the variants' bases form a cycle")
        if name not in (variants or {}):
            raise ConfigError(f"{path}.{chain[-1][0]}.base" if chain else path, f"unknown variant {name!r}")
        seen.add(name)
        spec = variants[name] or {}
        chain.append((name, spec))
        name = spec.get("base", NOMINAL)
    return chain[::-1]


def variant_config(machine_config, steps, operating_point=None, source=None):
    """The machine config of a variant.

    Parameters
    ----------
    machine_config : dict
        The nominal machine file.
    steps : list of dict
        In order, each with ``effects`` (entries to append) and/or
        ``update_effects`` (the effects of an update's machine.yaml: its
        `UPDATED_EFFECTS` replace the variant's own).
    operating_point : dict, optional
        ``{axis: {position_m, control_current_a}}`` from the calibration.
    source : str, optional
        Named in errors.

    Returns
    -------
    dict
        A machine config, checked by `ambid.machine.machine_from_config`.
    """
    config = copy.deepcopy(machine_config)
    if operating_point:
        config["bearings"]["radial"]["operating_point"] = copy.deepcopy(operating_point)
    effects = list(config.get("effects") or [])
    for step in steps:
        if step.get("update_effects") is not None:
            effects = [e for e in effects if e["name"] not in UPDATED_EFFECTS]
            effects += [copy.deepcopy(e) for e in step["update_effects"] if e["name"] in UPDATED_EFFECTS]
        effects += copy.deepcopy(list(step.get("effects") or []))
    config["effects"] = effects
    machine_from_config(config, source=source)  # every effect checked against the machine
    return config
