"""Start-up of the command line's help: ``hgjax --help`` and each command's ``--help``.

Runs each help as the console script a user types, in a fresh process, ``--repeats`` times, and
reports the median and the fastest wall-clock seconds, with the modules the help imported
(JAX and NumPy must not be among them). The target is 0.3 s on a quiet machine; the load
average at the start is printed beside the table, since a busy machine slows every start.

    python bench/cli_help.py [--repeats 7]

Writes bench/results/cli_help.md.
"""

import argparse
import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import time

from _report import write

COMMANDS = [[], ["resample"], ["score"], ["compare"], ["demo"]]
PROBE = ("import sys, runpy; sys.argv = ['hgjax', *sys.argv[1:]];"
         " import atexit; atexit.register(lambda: print('heavy:', ','.join(sorted(m for m in ('jax', 'numpy', 'scipy')"
         " if m in sys.modules)), file=sys.stderr));"
         " from hgjax.cli import main; main(sys.argv[1:])")


def _time(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def _heavy(command: list[str]) -> str:
    """The heavy modules (jax, numpy, scipy) that ``hgjax COMMAND --help`` imports."""
    done = subprocess.run([sys.executable, "-c", PROBE, *command, "--help"], capture_output=True, text=True,
                          check=True)
    found = [line for line in done.stderr.splitlines() if line.startswith("heavy:")]
    return found[-1].removeprefix("heavy:").strip() or "none"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    script = shutil.which("hgjax") or sys.exit("the hgjax console script is not on PATH (pip install -e .)")
    load = os.getloadavg()[0]
    _time([script, "--help"])  # warms the file cache
    table = ["| command | median s | fastest s | heavy modules imported |", "|---|---:|---:|---|"]
    times = [_time([sys.executable, "-c", "pass"]) for _ in range(args.repeats)]
    table.append(f"| `python -c pass` (the interpreter alone) | {statistics.median(times):.3f} | {min(times):.3f} | |")
    for command in COMMANDS:
        argv = [script, *command, "--help"]
        times = [_time(argv) for _ in range(args.repeats)]
        table.append(f"| `hgjax {' '.join([*command, '--help'])}` | {statistics.median(times):.3f} |"
                     f" {min(times):.3f} | {_heavy(command)} |")
        print(table[-1], flush=True)
    write(pathlib.Path(__file__).parent / "results" / "cli_help.md", "cli_help.py", None,
          title="Help start-up of the hgjax command line",
          paragraphs=[f"Each help run {args.repeats} times as the console script, in a fresh process; wall-clock"
                      f" seconds. {os.cpu_count()} cores, load average {load:.2f} at the start, Python"
                      f" {sys.version.split()[0]}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; the script"
                      f" {script}."
                      " Target: 0.3 s on a quiet machine, without JAX or NumPy."],
          table=table)


if __name__ == "__main__":
    main()
