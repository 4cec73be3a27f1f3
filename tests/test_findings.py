"""Findings: one table format for every stage's warnings and verdicts."""

import math

import pytest

from ambid.errors import AmbidError
from ambid.findings import Finding, read_findings, write_findings


def test_round_trip_most_severe_first(tmp_path):
    path = tmp_path / "findings.tsv"
    findings = [Finding("fit", "note", "floor_fallback", "DX/DX", "constant floor used"),
                Finding("fit", "failure", "fit_failed", "DX/NX", "chi2/dof 2025.75", 2025.75),
                Finding("fit", "warning", "at_bound", "delay_s", "at its lower bound", 1e-7)]
    write_findings(findings, path)
    back = read_findings(path)
    assert [f.severity for f in back] == ["failure", "warning", "note"]
    assert back[0] == findings[1]
    assert math.isnan(back[2].value)


def test_empty_table_and_bad_severity(tmp_path):
    path = tmp_path / "findings.tsv"
    write_findings([], path)
    assert read_findings(path) == []
    with pytest.raises(AmbidError, match="severity"):
        Finding("fit", "fatal", "x", "y", "z")
    (tmp_path / "other.tsv").write_text("a\tb\n1\t2\n")
    with pytest.raises(AmbidError, match="not a findings table"):
        read_findings(tmp_path / "other.tsv")
