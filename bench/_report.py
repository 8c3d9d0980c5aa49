"""Writing a benchmark's Markdown result: the command that produced it, then the table."""

from __future__ import annotations

import sys
from pathlib import Path


def write(path: Path, script: str, argv, *, title: str, paragraphs: list[str], table: list[str]) -> None:
    """Write a result to ``path`` (creating its folder) and say where.

    The page: ``title``, the command that reruns ``bench/<script>`` with ``argv`` (default:
    this process's arguments), the ``paragraphs`` and the ``table`` lines.
    """
    argv = argv if argv is not None else sys.argv[1:]
    lines = [f"# {title}", "", f"Command: `python bench/{script}{''.join(f' {a}' for a in argv)}`", ""]
    for paragraph in paragraphs:
        lines += [paragraph, ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines + table + [""]))
    print(f"wrote {path}")
