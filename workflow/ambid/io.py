"""File formats at the edge of the library: Parquet with units, tables, atomic writes.

Every Parquet file written by ambid carries its schema version and the unit of
each column in the file metadata (keys ``ambid.schema_version``,
``ambid.units`` as JSON, ``ambid.kind``).  Parquet has no complex type, so
complex values are stored as ``re`` / ``im`` columns.  Writes go to a
temporary file in the same directory that is renamed into place, so a crash
never leaves a half-written result.
"""

import contextlib
import hashlib
import json
import logging
import os
import sys
import tempfile
import traceback
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from .errors import AmbidError, ConfigError

__all__ = [
    "SCHEMA_VERSION",
    "rule_log",
    "atomic_path",
    "file_digest",
    "write_parquet",
    "read_parquet",
    "write_tsv",
    "read_tsv",
    "load_yaml",
    "read_yaml",
    "write_yaml",
    "frf_frame",
    "frf_from_frame",
]

SCHEMA_VERSION = "1"


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success only."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(handle)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(temporary, 0o666 & ~umask)  # mkstemp creates 0600; results are ordinary files
    try:
        yield Path(temporary)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def file_digest(path):
    """SHA-256 of a file's content (16 hex digits), or ``"missing"``.

    What the workflow tracks a user's file by (a rule param: Snakemake reruns what depends on it when the
    content changes, whatever its modification time), and what a converted log records of its source.
    """
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            while block := handle.read(2**20):
                digest.update(block)
    except OSError:
        return "missing"
    return digest.hexdigest()[:16]


def read_tsv(path):
    """A table written by `write_tsv`."""
    return pd.read_csv(path, sep="\t")


def _duplicate_keys(node, path=""):
    """The first key assigned twice in a composed YAML node tree: (dotted key, first line, second line) or None."""
    if isinstance(node, yaml.MappingNode):
        seen = {}
        for key_node, value_node in node.value:
            key = str(key_node.value)
            where = f"{path}.{key}" if path else key
            if key in seen:
                return where, seen[key] + 1, key_node.start_mark.line + 1
            seen[key] = key_node.start_mark.line
            found = _duplicate_keys(value_node, where)
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for k, item in enumerate(node.value):
            found = _duplicate_keys(item, f"{path}[{k}]")
            if found:
                return found
    return None


#: libyaml's safe loader where PyYAML was built with it (same resolver and marks, 8x faster: every Snakemake
#: invocation reads the config, machine and rig files; syntax errors are worded by libyaml)
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml(text, source):
    """A YAML document's content, refusing duplicate keys (YAML would silently keep the last value).

    Raises
    ------
    ConfigError
        Naming ``source``, the duplicated key's dotted path and both lines; or the syntax error.
    """
    try:
        node = yaml.compose(text, Loader=_SAFE_LOADER)
        duplicate = _duplicate_keys(node)
        if duplicate:
            key, first, second = duplicate
            raise ConfigError(key, f"duplicate key (lines {first} and {second}): YAML would keep only the last value",
                              source=str(source))
        return yaml.load(text, Loader=_SAFE_LOADER)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ConfigError("(file)", f"not valid YAML{where}: {problem}", source=str(source)) from None


def read_yaml(path, key="(file)"):
    """A YAML mapping from ``path`` (duplicate keys refused, `load_yaml`).

    Raises
    ------
    ConfigError
        Naming the file (and ``key``, the config key that points to it) when it cannot be read, is not
        valid YAML, repeats a key or is not a mapping.
    """
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(key, f"cannot read {path}: {error}") from None
    content = load_yaml(text, path)
    if not isinstance(content, dict):
        raise ConfigError(key, f"{path} does not hold a mapping")
    return content


def write_yaml(mapping, path, header=""):
    """Write a mapping as YAML atomically, after ``header`` comment lines (each starting with '#')."""
    with atomic_path(path) as temporary:
        temporary.write_text(header + yaml.safe_dump(mapping, sort_keys=False, width=110))


def write_parquet(frame, path, units, kind, metadata=None):
    """Write a DataFrame as Parquet with schema version, kind and column units.

    Parameters
    ----------
    frame : pandas.DataFrame
    path : str or Path
    units : dict
        Column name -> unit string; every numeric column must have one.
    kind : str
        What the file holds (``plant_frf``, ``identification_log``, ...).
    metadata : dict, optional
        Further JSON-serialisable metadata (machine, model variant, ...).
    """
    missing = [c for c in frame.columns if pd.api.types.is_numeric_dtype(frame[c]) and c not in units]
    if missing:
        raise AmbidError(f"{path}: no unit given for column(s) {missing}")
    table = pa.Table.from_pandas(frame, preserve_index=False)
    extra = {
        "ambid.schema_version": SCHEMA_VERSION,
        "ambid.kind": kind,
        "ambid.units": json.dumps(units, sort_keys=True),
        "ambid.metadata": json.dumps(metadata or {}, sort_keys=True),
    }
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **{k: v.encode() for k, v in extra.items()}})
    with atomic_path(path) as temporary:
        pq.write_table(table, temporary)


def read_parquet(path, kind=None):
    """Read a Parquet file written by `write_parquet`.

    Returns
    -------
    frame : pandas.DataFrame
    info : dict
        ``schema_version``, ``kind``, ``units`` and ``metadata``.

    Raises
    ------
    AmbidError
        If ``path`` is a directory, or the file lacks ambid metadata (the
        Parquet key-value metadata ``ambid.schema_version``, ``ambid.kind``,
        ``ambid.units``), has another schema version or kind.
    """
    if Path(path).is_dir():
        raise AmbidError(f"{path}: is a directory, not a Parquet file")
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowInvalid) as error:
        raise AmbidError(f"{path}: not a readable Parquet file ({error})") from None
    raw = table.schema.metadata or {}
    if b"ambid.schema_version" not in raw:
        raise AmbidError(
            f"{path}: no ambid metadata (the Parquet key-value metadata ambid.schema_version, ambid.kind and "
            f"ambid.units that ambid writes); a table written by other software is read by the plain-table reader: "
            f"`ambid check-log {path} --format table`, `ambid import {path} --machine M --run R --format table` "
            f"(README 'Bring your own logs')"
        )
    info = {
        "schema_version": raw[b"ambid.schema_version"].decode(),
        "kind": raw.get(b"ambid.kind", b"").decode(),
        "units": json.loads(raw.get(b"ambid.units", b"{}")),
        "metadata": json.loads(raw.get(b"ambid.metadata", b"{}")),
    }
    if info["schema_version"] != SCHEMA_VERSION:
        raise AmbidError(f"{path}: schema version {info['schema_version']}, this ambid reads {SCHEMA_VERSION}")
    if kind is not None and info["kind"] != kind:
        raise AmbidError(f"{path}: holds {info['kind']!r}, expected {kind!r}")
    return table.to_pandas(), info


def write_tsv(rows, path, float_format="%.6g"):
    """Write a list of dicts (or a DataFrame) as a tab-separated table, atomically."""
    frame = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows)
    with atomic_path(path) as temporary:
        frame.to_csv(temporary, sep="\t", index=False, float_format=float_format)


def frf_frame(frequency_hz, response, outputs, inputs):
    """Long-format table of a MIMO FRF: one row per (output, input, frequency).

    Parameters
    ----------
    frequency_hz : array (n_f,)
    response : complex array (n_f, n_out, n_in)
    outputs, inputs : sequences of axis names
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    n_f, n_out, n_in = response.shape
    out_index, in_index, f_index = np.meshgrid(np.arange(n_out), np.arange(n_in), np.arange(n_f), indexing="ij")
    values = response[f_index, out_index, in_index].ravel()
    return pd.DataFrame(
        {
            "output": np.asarray(outputs)[out_index.ravel()],
            "input": np.asarray(inputs)[in_index.ravel()],
            "frequency_hz": frequency_hz[f_index.ravel()],
            "re": values.real,
            "im": values.imag,
        }
    )


def frf_from_frame(frame, output, input):
    """Frequencies and complex values of one channel of an `frf_frame` table."""
    channel = frame[(frame["output"] == output) & (frame["input"] == input)].sort_values("frequency_hz")
    return channel["frequency_hz"].to_numpy(), channel["re"].to_numpy() + 1j * channel["im"].to_numpy()


def rule_log(log_path, name):
    """Set up a Snakemake rule script: its log and stderr go to ``log_path``.

    An `AmbidError` the script raises then ends it with its message, which
    names the file, line or key at fault, as one line on the console (and in
    the log) instead of a traceback; any other exception is a bug and keeps
    its traceback.  Snakemake removes the outputs of the failed job, and
    ambid writes every output atomically, so no partial result remains.

    Returns
    -------
    logging.Logger
        Logger ``name`` writing to the log file.
    """
    handle = open(log_path, "w")
    sys.stderr = handle
    logging.basicConfig(stream=handle, level=logging.INFO, format="%(asctime)s %(message)s")

    def report(kind, error, trace):
        if issubclass(kind, AmbidError):
            message = f"ambid error ({name}): {error}"
            print(message, file=handle)
            print(message, file=sys.__stderr__)
        else:
            traceback.print_exception(kind, error, trace, file=handle)
            traceback.print_exception(kind, error, trace, file=sys.__stderr__)
        handle.flush()

    sys.excepthook = report
    return logging.getLogger(name)
