"""A worker's allocator settings (``sim_worker/process_memory.py``), measured on a real process: freed arrays stay
resident until the heap is trimmed, and ``trim_heap`` gives them back. In a child process, so that this one's
allocator is left as it is."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, sys.argv[1])
    from sim_worker.process_memory import bound_heap, trim_heap
    import numpy as np

    def resident_mb():
        fields = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
        return int(fields["VmRSS"].split()[0]) / 1000

    tuned = bound_heap()
    base = resident_mb()
    blocks = [np.ones(8000) for _ in range(3000)]  # 64 kB each, under the mmap threshold: from the heap
    last = blocks[-1]  # held: the heap's top stays in use, so freeing the others cannot shrink it from the top
    full = resident_mb()
    del blocks
    freed = resident_mb()
    trimmed = trim_heap()
    print(json.dumps({"tuned": tuned, "trimmed": trimmed, "base": base, "full": full, "freed": freed,
                      "after": resident_mb()}))
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator, /proc")
def test_freed_arrays_stay_resident_until_the_heap_is_trimmed():
    out = subprocess.run([sys.executable, "-c", CHILD, str(ROOT)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    m = json.loads(out.stdout.strip().splitlines()[-1])
    assert m["tuned"] and m["trimmed"], m
    assert m["full"] - m["base"] > 150, m  # 3000 x 64 kB = 192 MB resident
    assert m["freed"] - m["base"] > 150, m  # freed, but still resident: the heap keeps it
    assert m["after"] - m["base"] < 30, m  # given back
