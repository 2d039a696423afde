"""Run one of the page's ES modules (touch4d/web/static/NAME.js) in node.js: the tests of the page's
pure parts (its touch, batching, pacing) feed it JSON on stdin and read JSON back."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from touch4d.configfile import CONFIG_DIR

STATIC = CONFIG_DIR.parent / "touch4d" / "web" / "static"


def run_page_module(tmp_path: Path, name: str, runner: str, payload) -> dict:
    """Copy static/NAME.js beside `runner` (a module importing './NAME.mjs'), run it with `payload`
    as JSON on stdin and return what it printed, parsed. Skipped only where node.js is missing
    (`./dev test` installs npm, which brings it)."""
    node = shutil.which("node") or shutil.which("nodejs")
    if node is None:
        pytest.skip("no node.js here (./dev test installs npm, which brings it)")
    (tmp_path / f"{name}.mjs").write_text((STATIC / f"{name}.js").read_text())
    (tmp_path / "run.mjs").write_text(runner)
    done = subprocess.run([node, str(tmp_path / "run.mjs")], input=json.dumps(payload), capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
