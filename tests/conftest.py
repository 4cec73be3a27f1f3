"""Shared fixtures: the default machines as configs, Machines and Plants."""

from pathlib import Path

import pytest
import yaml

from ambid.machine import machine_from_config
from ambid.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
MACHINE_DIR = ROOT / "config" / "machines"


def load_machine_config(name):
    with open(MACHINE_DIR / f"{name}.yaml") as handle:
        return yaml.safe_load(handle)


@pytest.fixture(scope="session")
def hs_config():
    return load_machine_config("hs_eden_like")


@pytest.fixture(scope="session")
def demo_config():
    return load_machine_config("demo20")


@pytest.fixture(scope="session")
def hs_machine(hs_config):
    return machine_from_config(hs_config)


@pytest.fixture(scope="session")
def demo_machine(demo_config):
    return machine_from_config(demo_config)


@pytest.fixture(scope="session")
def hs_plant(hs_machine):
    return Plant(hs_machine)


@pytest.fixture(scope="session")
def demo_plant(demo_machine):
    return Plant(demo_machine)


def pytest_collection_modifyitems(items):
    """Run the long tests first: the tests sharing an expensive fixture on one worker (``xdist_group``), then those
    that run Snakemake, then the rest.  Under pytest-xdist (``make test``) the short tests then fill the other
    worker's time instead of one long test finishing alone at the end; run serially, only the order changes."""
    def rank(item):
        return (item.get_closest_marker("xdist_group") is None, item.get_closest_marker("workflow") is None)

    items.sort(key=rank)
