"""The suite's two tiers and how pytest-xdist runs them: the README's fast and full test commands are the two
that .ci/run runs, alike but for their mark selection (every test in exactly one tier), and a crashed worker
fails the run instead of hanging it."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys
import textwrap

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
FAST, FULL = '-m "not full"', "-m full"


def test_readme_names_both_tiers_as_ci_runs_them():
    """The fast command closes the README's first bash block and the full one is named in the line right below it;
    .ci/run runs the same two, fast first, and nothing else under pytest."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"^```bash\n(.*?)^```\n([^\n]*)\n", readme, re.M | re.S)
    fast = block.group(1).splitlines()[-1].split("   #")[0].rstrip()
    full = re.findall(r"`([^`]*pytest[^`]*)`", block.group(2))
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if "pytest" in line and not line.startswith("#")]
    assert ci == [fast, *full] and len(full) == 1
    install, _, command = fast.partition(" && ")
    assert install == 'pip install ".[test]"' and command.replace(FAST, FULL) == full[0] and FAST in command


@pytest.mark.full
def test_a_crashed_worker_fails_the_run(tmp_path):
    """A worker killed by a fatal error (JAX's aborts are) is reported as a failure and the run ends; by default
    pytest-xdist starts a new worker, and under --dist loadgroup the run then never ends."""
    (tmp_path / "test_abort.py").write_text(textwrap.dedent("""
        import os

        def test_aborts():
            os.abort()

        def test_passes():
            pass
    """))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"), "--rootdir", str(tmp_path),
                           "-n", "2", "--dist", "loadgroup", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and "crashed while running 'test_abort.py::test_aborts'" in proc.stdout, proc.stdout[-3000:]
