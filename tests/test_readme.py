"""Every code block in README.md runs as written (``text`` blocks are synopses and transcripts, not code).

``sh`` blocks run in bash in a scratch directory, in the environment the README's own install produced (a
leading ``pip install ... &&`` is that install, so it is not repeated); the test command's block is what runs
this very test, so it is skipped. ``python`` blocks run in a fresh interpreter; ``toml`` blocks must parse.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

README = Path(__file__).resolve().parents[1] / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def blocks() -> list[tuple[str, str, int]]:
    text = README.read_text(encoding="utf-8")
    skip = text.index("<!-- test-command -->"), text.index("<!-- /test-command -->")
    found = []
    for m in FENCE.finditer(text):
        if skip[0] < m.start() < skip[1]:
            continue
        found.append((m.group(1), m.group(2), text.count("\n", 0, m.start()) + 1))
    return found


def test_every_block_has_a_language() -> None:
    untagged = [line for lang, _, line in blocks() if not lang]
    assert not untagged, f"README.md blocks without a language (sh, python, toml or text) at lines {untagged}"


@pytest.mark.parametrize(("lang", "code", "line"), [b for b in blocks() if b[0] in ("sh", "python", "toml")])
def test_block_runs_as_written(lang: str, code: str, line: int, tmp_path: Path) -> None:
    if lang == "toml":
        tomllib.loads(code)
        return
    if lang == "python":
        command = [sys.executable, "-c", code]
    else:
        script = re.sub(r"^pip install [^&\n]*&&\s*", "", code, flags=re.M)
        command = ["bash", "-euo", "pipefail", "-c", script]
    result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, f"README.md line {line}:\n{result.stdout}\n{result.stderr}"
