"""The README's rule graph is the workflow's."""

import importlib.util
import re

import pytest

from conftest import ROOT

pytestmark = pytest.mark.workflow


def test_readme_rule_graph_is_current():
    spec = importlib.util.spec_from_file_location("rulegraph", ROOT / "tools" / "rulegraph.py")
    rulegraph = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rulegraph)
    block = re.search(r"```mermaid\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    documented = rulegraph.rule_edges(block)
    assert len(documented) > 20
    assert documented == rulegraph.current_edges()
