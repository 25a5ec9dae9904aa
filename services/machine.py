"""One line describing the machine a measurement ran on (benchmarks, docs/RESULTS.md)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def machine_line(extra: str = "") -> str:
    """Return one line describing this machine (cores, CPU model, Python and numpy versions)."""
    import numpy as np

    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "default")
    return (
        f"Machine: nproc={os.cpu_count()}, {cpu}; Python {platform.python_version()}, numpy {np.__version__}; "
        f"BLAS threads {threads}{'; ' + extra if extra else ''}. Shared machine: timings are medians and indicative."
    )
