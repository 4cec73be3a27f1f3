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


#: Tests that share one expensive module fixture, by node-id prefix: each group runs on one pytest-xdist worker
#: (``make test``), so the fixture is made once.  (xdist's own ``--dist loadgroup`` with ``xdist_group`` marks
#: silently stops grouping on pytest 9.2, pytest-dev/pytest-xdist#1386; this does the same by node id.)
SHARED_FIXTURE_GROUPS = {
    "tests/test_reproducibility.py::": "two_runs",  # the two clean workflow runs
    "tests/test_calibration.py::TestProcedure::": "hs_calibration",  # one calibration run on the rig ...
    "tests/test_calibration.py::TestBadLogs::": "hs_calibration",  # ... which these alter
}


def shared_fixture_group(nodeid):
    return next((group for prefix, group in SHARED_FIXTURE_GROUPS.items() if nodeid.startswith(prefix)), None)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup``: every test on its own, except the `SHARED_FIXTURE_GROUPS`, largest first."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            return shared_fixture_group(nodeid) or nodeid

    return SharedFixtureScheduling(config, log)


def pytest_collection_modifyitems(items):
    """Run the long tests first: the shared-fixture groups, then the tests that run Snakemake, then the rest.  Under
    pytest-xdist the short tests then fill the other worker's time instead of one long test finishing alone at the
    end; run serially, only the order changes."""
    def rank(item):
        return shared_fixture_group(item.nodeid) is None, item.get_closest_marker("workflow") is None

    items.sort(key=rank)
