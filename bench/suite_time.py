"""Where the test suite's time goes: wall time and XLA compile time per test and per file.

Runs the README's test command (pytest-xdist, 2 workers) with this module loaded as a pytest
plugin in every worker: each test's call time and the XLA backend compile seconds inside it
(``jax.monitoring``'s ``/jax/core/compile/backend_compile_duration``: compilations in the
test's own process; CLI subprocesses, notebook kernels and Dask workers compile in theirs and
count as wall time only). The test command's duration, per-file sums and the longest tests go
to bench/results/suite_time.md.

    python bench/suite_time.py [--out bench/results/suite_time.md]
"""

import argparse
import collections
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
COMPILE = "/jax/core/compile/backend_compile_duration"
COMMAND = ["-m", "pytest", "-n", "2", "--dist", "loadgroup", "--pyargs", "hgjax", "tests"]

_current, _compile, _wall = [None], collections.Counter(), {}


def pytest_configure(config):
    """In a worker (or a run without xdist): listen to JAX's compile events."""
    import jax

    def listener(event, duration, **kwargs):
        if event == COMPILE and _current[0] is not None:
            _compile[_current[0]] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)


def pytest_runtest_call(item):
    _current[0] = item.nodeid


def pytest_runtest_logreport(report):
    if report.when == "call":
        _wall[report.nodeid] = report.duration
        _current[0] = None


def pytest_sessionfinish(session):
    folder = os.environ.get("HGJAX_SUITE_TIME_DIR")
    if folder:
        name = os.environ.get("PYTEST_XDIST_WORKER", "main")
        pathlib.Path(folder, f"{name}.json").write_text(json.dumps({"wall": _wall, "compile": _compile}))


def _report(seconds: float, summary: str, wall: dict, compiled: dict) -> str:
    def file_of(nodeid):
        return nodeid.split("::")[0].split("@")[0]

    per_file = collections.defaultdict(lambda: [0.0, 0.0, 0])
    for nodeid, s in wall.items():
        row = per_file[file_of(nodeid)]
        row[0] += s
        row[1] += compiled.get(nodeid, 0.0)
        row[2] += 1
    total, total_compile = sum(wall.values()), sum(compiled.values())
    lines = [
        "# Where the test suite's time goes",
        "",
        "Command: `python bench/suite_time.py`",
        "",
        f"The README's test command (`python -P {' '.join(COMMAND)}`, from the repository root) with this "
        "script loaded as a pytest plugin in both workers. Wall: each test's call time; compile: XLA backend "
        "compile seconds inside the call in the test's own process (subprocesses count as wall only).",
        "",
        f"- test command: {seconds:.0f} s ({summary})",
        f"- summed call time {total:.0f} s over {len(wall)} tests (both workers), of which XLA backend compiles "
        f"{total_compile:.0f} s ({total_compile / max(total, 1e-9):.0%})",
        "",
        "| file | tests | wall s | compile s |",
        "|---|---|---|---|",
    ]
    for name, (s, c, n) in sorted(per_file.items(), key=lambda kv: -kv[1][0]):
        lines.append(f"| {name} | {n} | {s:.1f} | {c:.1f} |")
    lines += ["", "Longest 30 tests:", "", "| test | wall s | compile s |", "|---|---|---|"]
    for nodeid, s in sorted(wall.items(), key=lambda kv: -kv[1])[:30]:
        lines.append(f"| `{nodeid.split('@')[0]}` | {s:.2f} | {compiled.get(nodeid, 0.0):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "suite_time.md"))
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, "HGJAX_SUITE_TIME_DIR": folder,
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "bench"), os.environ.get("PYTHONPATH")]))}
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, "-P", *COMMAND, "-p", "suite_time"], cwd=ROOT, env=env,
                              capture_output=True, text=True)
        seconds = time.perf_counter() - start
        wall, compiled = {}, {}
        for part in pathlib.Path(folder).glob("*.json"):
            data = json.loads(part.read_text())
            wall.update(data["wall"])
            compiled.update(data["compile"])
    summary = proc.stdout.strip().splitlines()[-1].strip("= ") if proc.stdout.strip() else f"exit {proc.returncode}"
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout[-5000:] + proc.stderr[-5000:])
        raise SystemExit(f"the test command failed (exit {proc.returncode}): {summary}")
    text = _report(seconds, summary, wall, compiled)
    pathlib.Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
