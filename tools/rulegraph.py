"""Print the workflow's rule graph as the Mermaid block of the README ("A tour of the DAG").

Run from the repository root: ``.venv/bin/python tools/rulegraph.py``.  The block lists every
dependency of ``snakemake --rulegraph mermaid-js`` by rule name, sorted, so it diffs cleanly;
tests/test_readme.py checks that the README's block is the current graph.
"""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def rule_edges(mermaid):
    """(upstream, downstream) rule pairs of a Mermaid flowchart (``idN[name]`` nodes or bare names)."""
    names = dict(re.findall(r"^\s*(id\d+)\[(\w+)\]", mermaid, re.M))
    pairs = re.findall(r"^\s*(\w+)\s*-->\s*(\w+)", mermaid, re.M)
    return sorted({(names.get(a, a), names.get(b, b)) for a, b in pairs})


def current_edges():
    result = subprocess.run([sys.executable, "-m", "snakemake", "--rulegraph", "mermaid-js"], cwd=ROOT,
                            capture_output=True, text=True, check=True)
    return rule_edges(result.stdout)


def main():
    print("```mermaid\nflowchart LR")
    for upstream, downstream in current_edges():
        print(f"    {upstream} --> {downstream}")
    print("```")


if __name__ == "__main__":
    main()
