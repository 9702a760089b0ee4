"""Every script in examples/ runs with no arguments, quickly, without an error."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.py"))
# Each example promises to finish in well under this on a laptop; the margin is for
# shared, loaded machines.
TIMEOUT_S = 90


def test_there_are_examples():
    names = {p.name for p in EXAMPLES}
    assert {"hook_into_pipeline.py", "wrap_your_model.py", "evaluate.py"} <= names


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_runs(script, tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert done.stdout.strip(), "an example should say what it did"
