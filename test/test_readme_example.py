"""The README's 20-line ROS-free example runs as printed and the fusion of VO alone reproduces the VO."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_example_runs(pvo_data: Path) -> None:
    block = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert block is not None
    code = block.group(1)
    assert len(code.strip().splitlines()) <= 20
    env = dict(os.environ, PVO_DATA_DIR=str(pvo_data))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert [line.split()[0] for line in lines] == ["VO", "fused"]
    # without aiding measurements the smoother reproduces the VO: the same end error to the printed mm
    assert lines[0].split()[1] == lines[1].split()[1]
