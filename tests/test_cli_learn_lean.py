"""`contact-skills learn` as lean as the service: one BLAS thread, a summary that reads the demonstration once, a
too-long CSV refused while it is still being read (issue 28)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from cli.learn_command import summary_lines
from cli.main import main
from corpus.synthetic import plane_slide
from schemas import Demonstration, SegmentKind
from services import csv_import
from services.local_processes import THREAD_LIMIT_ENV
from skills.parameterize import learn_skill

REPO = Path(__file__).resolve().parents[1]

FRESH = """
import json, sys
from pathlib import Path
from cli.main import main
code = main(["learn", sys.argv[1], "--type", "slide", "-o", str(Path(sys.argv[1]).with_name("skill.json"))])
from threadpoolctl import threadpool_info
print(json.dumps({"code": code, "after": sorted({lib["num_threads"] for lib in threadpool_info()})}))
"""
"""A fresh process running `contact-skills learn` (nothing imported before it), printing the thread counts of the
BLAS/OpenMP libraries it loaded, seen by threadpoolctl after the command returned."""

LOADED = """
import json, sys
from pathlib import Path
import skills.parameterize as parameterize  # numpy, scipy and sklearn loaded, a thread per core
from cli.main import main
from threadpoolctl import threadpool_info

learn, during = parameterize.learn_skill, []
def observed_learn(*args, **kwargs):
    during.append(sorted({lib["num_threads"] for lib in threadpool_info()}))
    return learn(*args, **kwargs)
parameterize.learn_skill = observed_learn  # learn_and_report imports it from the module when called
code = main(["learn", sys.argv[1], "--type", "slide", "-o", str(Path(sys.argv[1]).with_name("skill.json"))])
print(json.dumps({"code": code, "during": during, "after": sorted({lib["num_threads"] for lib in threadpool_info()})}))
"""
"""`contact-skills learn` called in a process whose BLAS is already loaded: the thread counts while the skill is
learned and after the command returned."""


def _demonstration_json(path: Path) -> Path:
    d = plane_slide(duration_s=3.0)
    path.write_text(Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches).model_dump_json())
    return path


def _threads(script: str, demo: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_LIMIT_ENV}  # the library defaults: a thread per core
    env["PYTHONPATH"] = str(REPO)
    result = subprocess.run(
        [sys.executable, "-c", script, str(demo)], cwd=REPO, env=env, capture_output=True, text=True, timeout=180
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: a BLAS has one thread anyway")
def test_learn_runs_its_blas_on_one_thread(tmp_path):
    """Started fresh (numpy not yet loaded), the BLAS loads with one thread and keeps it; called in a process whose BLAS
    already runs one thread per core, the learning still runs on one, and the process gets its threads back after."""
    demo = _demonstration_json(tmp_path / "demo.json")
    fresh = _threads(FRESH, demo)
    assert fresh == {"code": 0, "after": [1]}, fresh
    loaded = _threads(LOADED, demo)
    assert loaded["code"] == 0 and loaded["during"] == [[1]], loaded
    assert max(loaded["after"]) > 1, loaded  # the library default (a thread per core), given back


def test_the_summary_reads_the_demonstration_once(monkeypatch):
    """However many segments, the summary converts the demonstration's samples to arrays once (it did per segment:
    26 s of summary against 6.5 s of learning on a long recording), and its lines are those of this skill."""
    d = plane_slide(duration_s=6.0)
    demonstration = Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches)
    skill = learn_skill(demonstration)
    contact = [s for s in skill.segments if s.kind == SegmentKind.contact]
    assert contact and len(skill.segments) >= 3
    conversions = []
    arrays = Demonstration.arrays
    monkeypatch.setattr(Demonstration, "arrays", lambda self: conversions.append(1) or arrays(self))
    lines = summary_lines(demonstration, skill)
    assert len(conversions) == 1
    assert lines[0].startswith(f"demonstration (unnamed): {len(d.t)} samples")
    assert f"segments: {len(skill.segments)}" in lines
    assert sum("DMP reproduction RMS" in line for line in lines) == len(skill.segments)


def test_a_too_long_csv_is_refused_while_it_is_read(tmp_path):
    """A file with more rows than a recording may have, followed by ~390 MB (sparse: nothing written) that reading it
    in full would load: refused after reading just past the row limit, naming the limit, fast and in little memory."""
    path = tmp_path / "long.csv"
    rows = csv_import.MAX_CSV_ROWS + 10
    with path.open("wb") as f:
        f.write(b"t,px,py,pz,qx,qy,qz,qw,fx,fy,fz\n" + b"0\n" * rows)
        f.truncate(csv_import.MAX_CSV_BYTES - 1)  # under the size limit: only the row count can refuse it
    out, err = io.StringIO(), io.StringIO()
    tracemalloc.start()
    started = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["learn", str(path), "-o", str(tmp_path / "skill.json")])
    elapsed = time.perf_counter() - started
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert code == 2, err.getvalue()
    message = err.getvalue()
    assert "contact-skills learn: error: " in message and "too many rows: at least " in message, message
    assert f"at most {csv_import.MAX_CSV_ROWS} data rows" in message, message
    read_lines = int(message.split("too many rows: at least ")[1].split(" lines")[0])
    assert csv_import.MAX_CSV_ROWS + 1 < read_lines <= rows + 1
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MiB traced: the file was read past the limit"
    assert elapsed < 10.0, f"refused after {elapsed:.1f} s"
    assert not (tmp_path / "skill.json").exists()


def test_a_csv_file_within_the_limits_is_read_whole(tmp_path):
    """The chunked read returns the whole file: a recording longer than one chunk imports every row."""
    d = plane_slide(rate_hz=1000.0, duration_s=30.0)
    rows = np.column_stack([d.t, d.positions, d.orientations, d.wrenches[:, :3]])
    path = tmp_path / "slide.csv"
    np.savetxt(path, rows, delimiter=",", header="t,px,py,pz,qx,qy,qz,qw,fx,fy,fz", comments="", fmt="%.17g")
    assert path.stat().st_size > csv_import.READ_CHUNK_BYTES  # more than one chunk
    imported = csv_import.demonstration_from_csv(path)
    assert imported.n_samples == len(d.t)
    np.testing.assert_allclose(imported.arrays().positions[[0, -1]], d.positions[[0, -1]], rtol=0, atol=1e-12)
