"""Findings: the warnings and verdicts a stage writes next to its results, for the user to read.

Anything the user must know about a result (a fit that failed, a parameter at
its search bound, a variable the data do not determine, an outlier step that
was excluded, an unstable loop, a misfit no effect explains, a floor that fell
back to a constant) is a `Finding`.  Each stage writes its findings as one
small table, ``findings.tsv`` next to its outputs, in the one format of
`write_findings`; the report reads them back (`read_findings`) and shows each
where the result it qualifies is quoted.  Nothing the user must know lives only
in ``logs/``.
"""

import math
from dataclasses import asdict, dataclass

import pandas as pd

from .errors import AmbidError
from .io import write_tsv

__all__ = ["SEVERITIES", "Finding", "findings_frame", "write_findings", "read_findings"]

#: How much a finding matters, least first: ``note`` (how a result was obtained), ``warning`` (a result to
#: read with care), ``failure`` (a result that must not be used as it is).
SEVERITIES = ("note", "warning", "failure")
COLUMNS = ("stage", "severity", "code", "subject", "message", "value")


@dataclass(frozen=True)
class Finding:
    """One warning or verdict about a result.

    Parameters
    ----------
    stage : str
        The stage that found it (``frf``, ``fit``, ``update``, ``model``, ``compare``, ``diagnose``, ...).
    severity : str
        One of `SEVERITIES`.
    code : str
        What kind of finding, machine-readable and stable (``fit_failed``, ``at_bound``,
        ``undetermined``, ``outlier_excluded``, ``unstable``, ``unexplained_misfit``,
        ``floor_fallback``, ``truncation``, ...).
    subject : str
        What it is about, in the report's naming (a channel ``DX/NX``, a parameter
        ``amplifier_lowpass.cutoff_hz``, a design variable, an axis).
    message : str
        One or two sentences a machine engineer can act on.
    value : float
        The number the finding is about, where there is one (NaN otherwise).
    """

    stage: str
    severity: str
    code: str
    subject: str
    message: str
    value: float = math.nan

    def __post_init__(self):
        if self.severity not in SEVERITIES:
            raise AmbidError(f"finding {self.code!r}: severity {self.severity!r} is not one of {SEVERITIES}")


def findings_frame(findings):
    """The findings as a table with the columns of `write_findings`, most severe first (stable otherwise)."""
    frame = pd.DataFrame([asdict(f) for f in findings], columns=list(COLUMNS))
    rank = frame["severity"].map({s: -k for k, s in enumerate(SEVERITIES)})
    return frame.iloc[rank.argsort(kind="stable").to_numpy()].reset_index(drop=True)


def write_findings(findings, path):
    """Write findings as a tab-separated table (atomically); an empty table when there are none."""
    write_tsv(findings_frame(findings), path)


def read_findings(path):
    """Findings written by `write_findings`, as a list of `Finding`."""
    frame = pd.read_csv(path, sep="\t", keep_default_na=False, na_values={"value": [""]}, dtype={"value": float})
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise AmbidError(f"{path}: not a findings table (missing column(s) {missing})")
    return [Finding(**{c: row[c] for c in COLUMNS}) for row in frame.to_dict("records")]
