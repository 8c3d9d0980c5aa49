"""Every notebook in notebooks/ runs top to bottom (nbclient, from the notebooks folder) and prints
the figures its stored outputs show."""

import copy
import os
import pathlib
import re

import numpy as np
import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|[-+]?inf|nan")
TIMINGS = (
    (re.compile(r"^(\w+ +\d+) +\d+\.\d+ +\d+\.\d+ ", re.M), r"\1 "),  # a method's row: its cold and warm seconds
    (re.compile(r"ran in \d+ s"), "ran in"),
    (re.compile(r"<[^<>]*>"), ""),  # an object's repr (a figure's size), which the plotting backend decides
)
"""What varies from run to run: wall-clock seconds and object reprs, left out of the comparison."""


def printed(cell) -> str:
    """What a code cell printed or returned as text (not what it displayed), its timings left out."""
    text = "".join(out["text"] if out["output_type"] == "stream" else out.get("data", {}).get("text/plain", "")
                   for out in cell.get("outputs", []) if out["output_type"] in ("stream", "execute_result")
                   and out.get("name", "stdout") == "stdout")
    for pattern, replacement in TIMINGS:
        text = pattern.sub(replacement, text)
    return text


def figures(text: str) -> np.ndarray:
    return np.array([float(number) for number in NUMBER.findall(text)])


def test_figures_leave_out_the_seconds_and_the_displays():
    row = {"outputs": [{"output_type": "stream", "text": "hkc       1600    4.96    0.24      0.403   0.805\n"},
                       {"output_type": "stream", "text": "notebook ran in 39 s\n"},
                       {"output_type": "display_data", "data": {"text/plain": "<Figure size 500x300 with 1 Axes>"}},
                       {"output_type": "execute_result", "data": {"text/plain": "<Figure size 500x300 with 1 Axes>"}},
                       {"output_type": "execute_result", "data": {"text/plain": "0.25"}}]}
    assert figures(printed(row)).tolist() == [1600, 0.403, 0.805, 0.25]


@pytest.mark.full
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_and_prints_its_stored_figures(path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    root = str(path.parents[1])  # the kernel imports hgjax from this source tree, installed or not
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    stored = nbformat.read(path, as_version=4)
    nb = copy.deepcopy(stored)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(path.parent)}}).execute()
    errors = [out for cell in nb.cells if cell.cell_type == "code" for out in cell.get("outputs", [])
              if out.get("output_type") == "error"]
    assert not errors
    for index, (before, now) in enumerate(zip(stored.cells, nb.cells)):
        if now.cell_type != "code":
            continue
        expected, got = printed(before), printed(now)
        assert figures(got).shape == figures(expected).shape, f"cell {index} prints\n{got}\nstored\n{expected}"
        assert np.allclose(figures(got), figures(expected), rtol=0.02, atol=0.005, equal_nan=True), (
            f"cell {index} prints\n{got}\nstored\n{expected}")
