"""Machine configs: the defaults load; every inconsistency names its key."""

import copy

import pytest
from snakemake.utils import validate

from ambid.errors import ConfigError
from ambid.machine import machine_from_config

from conftest import ROOT

SCHEMA = str(ROOT / "workflow/schemas/machine.schema.yaml")


@pytest.mark.parametrize("name", ["hs_eden_like_config", "demo_config"])
def test_default_configs_pass_the_schema(name, request, hs_config, demo_config):
    validate(copy.deepcopy(hs_config if name.startswith("hs") else demo_config), SCHEMA)


def test_hs_eden_like_has_the_thesis_design_groups(hs_machine):
    groups = {tag: len(hs_machine.rotor.elements_tagged(tag)) for tag in ("de_amb", "nde_amb", "motor")}
    assert groups == {"de_amb": 4, "nde_amb": 4, "motor": 6}  # 14 design variables (thesis ch. 6.3)
    assert hs_machine.radial_bearings[0].electromagnet.bias_current_a == 5.0


def test_demo20_is_twenty_equal_elements(demo_machine):
    assert demo_machine.rotor.n_elements == 20
    assert len({(e.length_m, e.outer_diameter_m) for e in demo_machine.rotor.elements}) == 1
    assert demo_machine.rotor.elements_tagged("design") == [4, 5, 6, 7]  # thesis elements 5-8


def mutate(config, path, value):
    config = copy.deepcopy(config)
    node = config
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return config


@pytest.mark.parametrize(
    "path, value, key",
    [
        (("rotor", "elements", 0, "length_m"), -0.02, r"rotor.elements\[0\].length_m"),
        (("rotor", "elements", 1, "material"), "unobtainium", r"rotor.elements\[1\].material"),
        (("rotor", "elements", 0, "inner_diameter_m"), 0.5, r"rotor.elements\[0\].inner_diameter_m"),
        (("rotor", "sleeves", 0, "tag"), "nowhere", r"rotor.sleeves\[0\].tag"),
        (("rotor", "disks", 0, "node"), 999, r"rotor.disks\[0\].node"),
        (("bearings", "radial", "DE", "sensor_position_m"), 3.0, r"bearings.radial.DE.sensor_position_m"),
        (("bearings", "radial", "electromagnet", "nominal_air_gap_m"), 0.0, r"bearings.radial.electromagnet.nominal_air_gap_m"),
        (("controller", "radial", "derivative_filter_hz"), 5e4, r"controller.radial.derivative_filter_hz"),
        (("controller", "radial", "gain"), 1.0, r"controller.radial.gain"),
        (("materials", "steel", "density_kg_m3"), KeyError, r"materials.steel.density_kg_m3"),
        (("effects",), [{"name": "teleport"}], r"effects\[0\].name"),
    ],
)
def test_inconsistent_config_names_the_key(hs_config, path, value, key):
    with pytest.raises(ConfigError, match=key) as error:
        machine_from_config(mutate(hs_config, path, value), source="config/machines/hs_eden_like.yaml")
    assert "hs_eden_like.yaml" in str(error.value)


@pytest.mark.parametrize(
    "path, value, fragment",
    [
        (("rotor", "colour"), "red", "colour"),
        (("rotor", "elements", 0, "length_m"), -1.0, "length_m"),
        (("effects",), [{"name": "teleport"}], "teleport"),
    ],
)
def test_schema_rejects_unknown_keys_and_bad_values(hs_config, path, value, fragment):
    with pytest.raises(Exception, match=fragment):
        validate(mutate(hs_config, path, value), SCHEMA)
