"""Aligned tables for humans (widths in terminal cells: a CJK character takes two), colour, JSON for scripts."""

from __future__ import annotations

import json
import os
import sys
import unicodedata
from collections.abc import Sequence
from typing import Any, TextIO


def cells(text: str) -> int:
    """Terminal cells ``text`` takes: East Asian wide and fullwidth characters count 2, combining marks 0."""
    width = 0
    for ch in text:
        if unicodedata.combining(ch):
            continue
        width += 2 if unicodedata.east_asian_width(ch) in ("W", "F") else 1
    return width


def pad(text: str, width: int) -> str:
    return text + " " * max(0, width - cells(text))


def table(
    headers: Sequence[str],
    rows: Sequence[Sequence[object]],
    out: TextIO | None = None,
    *,
    widths: Sequence[int] | None = None,
    styles: Sequence[str | None] | None = None,
) -> list[int]:
    """Print an aligned table; returns the column widths used (pass them back for stable live views).

    ``styles`` gives one colour name (see :data:`COLOURS`) or None per row.
    """
    out = out or sys.stdout
    grid = [[str(h) for h in headers]] + [["" if c is None else str(c) for c in row] for row in rows]
    used = [max(cells(row[i]) for row in grid) for i in range(len(headers))]
    if widths is not None:
        used = [max(a, b) for a, b in zip(used, widths, strict=False)] + used[len(widths) :]
    colour = use_colour(out)
    for n, row in enumerate(grid):
        line = "  ".join(pad(c, w) for c, w in zip(row, used, strict=True)).rstrip()
        style = styles[n - 1] if styles is not None and n > 0 and n - 1 < len(styles) else None
        out.write(paint(line, style) if colour and style else line)
        out.write("\n")
        if n == 0:
            out.write("  ".join("-" * w for w in used) + "\n")
    return used


COLOURS = {"fault": "\x1b[1;31m", "offline": "\x1b[2;37m", "warning": "\x1b[33m", "ok": "\x1b[32m"}
_RESET = "\x1b[0m"


def use_colour(out: TextIO) -> bool:
    """Colour only on a terminal, and never when ``NO_COLOR`` is set (https://no-color.org)."""
    if os.environ.get("NO_COLOR"):
        return False
    isatty = getattr(out, "isatty", None)
    return bool(isatty and isatty())


def paint(text: str, style: str | None) -> str:
    code = COLOURS.get(style or "")
    return f"{code}{text}{_RESET}" if code else text


def emit_json(data: Any, out: TextIO | None = None) -> None:
    out = out or sys.stdout
    json.dump(data, out, ensure_ascii=False, indent=2, default=str)
    out.write("\n")


def emit_json_line(data: Any, out: TextIO | None = None) -> None:
    """One JSON object on one line, flushed: the stream of a long-running command (``serve``, ``opcua``)."""
    out = out or sys.stdout
    out.write(json.dumps(data, ensure_ascii=False, default=str) + "\n")
    out.flush()
