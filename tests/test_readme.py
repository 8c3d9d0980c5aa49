"""README.md runs as pasted: its Python blocks in a fresh interpreter, in order, sharing one namespace
as a reader's session would (the first under warnings as errors), the Dask block as a script of its
own (`if __name__ == "__main__":` on a 2-worker LocalCluster); its set-up commands are CI's; its
speed table is the one of the results file it links; its local links exist."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys
import textwrap

import pytest

import hgjax

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TIMEOUT = 600  # seconds per interpreter; the blocks take well under a minute on 2 cores


def blocks(language: str) -> list[str]:
    return [b for lang, b in re.findall(r"^```(\w*)\n(.*?)^```", README.read_text(), re.M | re.S) if lang == language]


def is_script(block: str) -> bool:
    """A block that starts worker processes runs as a script of its own."""
    return 'if __name__ == "__main__":' in block


def is_pending(block: str) -> bool:
    """A block that uses `hgjax.survey` (not yet in the package)."""
    return "hgjax.survey" in block


def run(tmp_path: pathlib.Path, name: str, source: str) -> subprocess.CompletedProcess:
    path = tmp_path / name
    path.write_text(source)
    proc = subprocess.run([sys.executable, str(path)], cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    return proc


DRIVER = textwrap.dedent('''
    import sys, warnings
    blocks = {blocks!r}
    namespace = {{"__name__": "readme"}}
    for i, block in enumerate(blocks):
        print(f"--- README python block {{i + 1}} of {{len(blocks)}}", flush=True)
        with warnings.catch_warnings():
            if i == 0:
                warnings.simplefilter("error")  # the first snippet raises no warning
            exec(compile(block, f"README.md python block {{i + 1}}", "exec"), namespace)
''')


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= 200


def test_every_python_block_is_run_by_one_test():
    python = blocks("python")
    assert python and not is_script(python[0]) and not is_pending(python[0])
    assert sum(map(is_script, python)) >= 1, "the Dask snippet runs inside if __name__ == '__main__'"
    assert all(not (is_script(b) and is_pending(b)) for b in python)


@pytest.mark.full
def test_python_blocks_run_in_order(tmp_path):
    """Every block but the scripts and the pending ones, in one interpreter and one namespace."""
    shared = [b for b in blocks("python") if not is_script(b) and not is_pending(b)]
    run(tmp_path, "readme_blocks.py", DRIVER.format(blocks=shared))


@pytest.mark.full
@pytest.mark.parametrize("index", [i for i, b in enumerate(blocks("python")) if is_script(b)])
def test_script_block_runs_as_main(tmp_path, index):
    run(tmp_path, f"readme_script_{index + 1}.py", blocks("python")[index])


@pytest.mark.full
@pytest.mark.skipif(not hasattr(hgjax, "survey"), reason="hgjax.survey has not landed yet")
@pytest.mark.parametrize("index", [i for i, b in enumerate(blocks("python")) if is_pending(b)])
def test_survey_block_runs_alone(tmp_path, index):
    run(tmp_path, f"readme_survey_{index + 1}.py", blocks("python")[index])


def test_setup_commands_are_the_first_block_and_the_test_command_is_ci():
    first = re.search(r"^```(\w*)\n(.*?)^```", README.read_text(), re.M | re.S)
    assert first.group(1) == "bash"
    commands = [line.split("   #")[0].rstrip() for line in first.group(2).splitlines()]
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith('pip install ".[test]"')]
    assert commands == ['pip install ".[plot,las]" && hgjax demo', ci[0]] and len(ci) == 1


def test_local_links_exist():
    links = re.findall(r"\]\(([^)#]+)\)", README.read_text())
    assert links
    for link in links:
        if "://" not in link:
            assert (ROOT / link).exists(), link


def _speed_rows():
    """speed_own_search.md's '/ floor here', '/ own search' and peak MB of each method at 1e6, and speed.md's 1e7
    tiled ratio."""
    results = ROOT / "bench" / "results"
    rows, tiled = {}, {}
    for line in (results / "speed_own_search.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 15 and cells[0] == "1e+06" and cells[5]:  # a method's row (the yardsticks': no floor here)
            rows[cells[1]] = (cells[6], cells[8], cells[14])
    for line in (results / "speed.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 9 and cells[1] == "tiled":
            tiled[cells[0]] = cells[7]
    return rows, tiled


def test_speed_table_is_the_linked_results_files():
    """Each row of the README's speed table: the results files' figures for that method, nothing else; every
    method timed at 1e6 has its row, and every registered method but fps (O(N M), timed to 1e5) is timed."""
    rows, tiled = _speed_rows()
    table = [line for line in README.read_text().splitlines() if re.match(r"\| `\w+` \| [\d.]+ \|", line)]
    methods = set()
    for line in table:
        method, floor, search, peak, scale = (c.strip() for c in line.strip("|").split("|"))
        method = method.strip("`")
        methods.add(method)
        assert (floor, search, peak) == rows[method], method
        assert scale == tiled.get(method, ""), method
    assert methods == set(rows) == set(hgjax.METHODS) - {"fps"}


@pytest.mark.full
def test_command_line_block_runs_as_written(tmp_path, cli_cache):
    """Each line of the command-line block, in order, in a folder beside ../shared (as a fresh clone is)."""
    shared = ROOT.parent / "shared"
    if not (shared / "data").is_dir():
        pytest.skip("../shared/data is not beside the checkout")
    (tmp_path / "shared").symlink_to(shared)
    work = tmp_path / "clone"
    work.mkdir()
    block = next(b for b in blocks("bash") if b.startswith("hgjax "))
    for line in block.splitlines():
        command = line.split("   #")[0].split()
        assert command[0] == "hgjax", line
        proc = subprocess.run([sys.executable, "-m", "hgjax", *command[1:]], cwd=work, capture_output=True, text=True,
                              timeout=TIMEOUT)
        assert proc.returncode == 0, f"{line}\n{proc.stderr[-3000:]}"
    for made in ("kept.ply", "lamppost.laz", "edges.laz", "kept/scan_lamppost.laz", "kept/scan_table_mug.laz",
                 "scored.pcd"):
        assert (work / made).stat().st_size > 0, made
    assert any((work / "out").iterdir())
