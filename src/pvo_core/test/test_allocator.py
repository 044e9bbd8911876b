"""The allocator tuning takes effect: after it, a large block freed and allocated again costs no new page
faults (the heap keeps it), where glibc's defaults would map and fault it in again."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import resource, sys
import numpy as np
from pvo_core.allocator import keep_large_blocks
if sys.argv[1] == "tuned":
    assert keep_large_blocks()
for _ in range(3):
    np.ones(40_000_000, dtype=np.uint8)  # warm-up: 40 MB allocated, touched, freed
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    np.ones(40_000_000, dtype=np.uint8)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


def test_freed_large_blocks_are_reused_without_page_faults() -> None:
    # 40 MB is above glibc's largest dynamic mmap threshold (32 MB): by default every such block is mapped
    # afresh and faulted in again (here ~2,800 faults for the five, transparent huge pages taking most of
    # the 4 KiB ones); tuned, the heap keeps it and the five allocations fault in (almost) nothing
    default, tuned = faults("default"), faults("tuned")
    assert tuned < 100
    assert default > 5 * (tuned + 20)
