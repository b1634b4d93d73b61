"""``nodes.memory.keep_freed_memory``: with it, buffers allocated again at every frame reuse their pages (few
minor page faults); without it, glibc maps fresh pages for each. Measured in fresh processes."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from depthguard.nodes.memory import keep_freed_memory

_PROBE = """
import json, resource, sys
import numpy as np
from depthguard.nodes.memory import keep_freed_memory
got = keep_freed_memory() if sys.argv[1] == "keep" else "default"
faults = []
for _ in range(6):  # one frame: a 1.2 MB copy of the payload, a float32 image made from it, both freed
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    payload = bytes(bytearray(1_228_800))
    img = np.frombuffer(payload, np.float32).reshape(480, 640) + 1.0
    img.sum()
    del payload, img
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
print(json.dumps({"got": got, "faults": faults}))
"""


def _probe(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_frames_reuse_their_pages_once_freed_memory_is_kept():
    keep, plain = _probe("keep"), _probe("plain")
    if keep["got"] != "kept":
        pytest.skip(f"this C library does not keep freed memory: {keep['got']}")
    pages = 2 * 1_228_800 // 4096  # (the two buffers of a frame)
    assert min(plain["faults"][2:]) > pages // 2, plain  # glibc's default: fresh pages at every frame
    assert max(keep["faults"][2:]) < pages // 10, keep  # kept: the pages of the last frame


def test_keep_freed_memory_says_what_it_got():
    got = keep_freed_memory()
    assert got == "kept" or got.startswith("not kept: ")
