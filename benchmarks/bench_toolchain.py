"""ROS 2 bag import and MCAP/CSV/JSON export: time and size.

Import: a 60 s demonstration (``corpus.synthetic.plane_slide``) written as a ROS 2 bag by ``rosbags`` with a
WrenchStamped and a PoseStamped topic at 1 kHz each (tests/rosbag_files.py: header stamps, messages logged out of
order), in MCAP and in sqlite3 storage, imported by ``services.bag_import.demonstration_from_bag`` (read, align,
tare, validate). Export: a real execution in PyBullet (``slide_flat``, teacher seed 0), its first 10 s of telemetry
(the API's stored matrix) as MCAP, CSV and JSON through ``GET /executions/{id}/telemetry`` (in-process app).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from benchmarks.report import median_time, pin_blas_threads, report_main, report_text

pin_blas_threads()

import numpy as np  # noqa: E402

SECTION = "bench_toolchain"
COMMAND = ".venv/bin/python benchmarks/bench_toolchain.py"
BAG_SECONDS = 60.0
EXPORT_SECONDS = 10.0


def import_rows(repeats: int, bag_seconds: float) -> tuple[list[str], dict[str, float]]:
    from rosbag_files import write_bag

    from corpus.synthetic import plane_slide
    from schemas.import_options import BagImportOptions
    from services.bag_import import demonstration_from_bag

    demo = plane_slide(duration_s=bag_seconds, rate_hz=1000.0)
    rows, seconds = [], {}
    with tempfile.TemporaryDirectory() as folder:
        for storage in ("mcap", "sqlite3"):
            bag = write_bag(Path(folder) / storage, demo.t, demo.positions, demo.orientations, demo.wrenches,
                            storage=storage, wrench_frame="world", pose_every=1)  # fmt: skip
            size = sum(p.stat().st_size for p in bag.iterdir())
            elapsed, imported = median_time(
                lambda bag=bag: demonstration_from_bag(bag, BagImportOptions(wrench_convention="measured-on-tool")),
                repeats,
            )
            seconds[storage] = elapsed
            messages = sum(imported.metadata.extra["bag"]["messages"].values())
            rows.append(f"| {storage} | {messages} | {size / 1e6:.1f} | {imported.n_samples} | {elapsed:.2f} | "
                        f"{messages / elapsed / 1e3:.0f} |")  # fmt: skip
    return rows, seconds


def export_rows(
    repeats: int, export_seconds: float, move_duration_s: float | None
) -> tuple[list[str], dict[str, tuple[float, int]]]:
    """The export table's rows and (median s, bytes) per format: the first ``export_seconds`` of a teacher's
    ``slide_flat`` (its stroke lasting ``move_duration_s``, None: the scenario's own) learned and executed."""
    from fastapi.testclient import TestClient

    from schemas import ExecutionSettings
    from services.app import create_app
    from services.settings import ServiceSettings
    from services.store import Store
    from sim_worker.executor import execute_skill
    from sim_worker.teacher import record_demonstration
    from skills.parameterize import learn_skill

    overrides = {} if move_duration_s is None else {"move_duration_s": move_duration_s}
    recording = record_demonstration("slide_flat", seed=0, **overrides)
    result = execute_skill(learn_skill(recording.demonstration), recording.world_config, ExecutionSettings())
    rows, measured = [], {}
    with tempfile.TemporaryDirectory() as folder:
        store = Store(Path(folder) / "bench.db")
        execution = store.executions.add({}, None)
        store.telemetry.add(execution.id, result.telemetry.to_batch(execution.id))
        samples = int((store.telemetry.rows(execution.id)[:, 0] <= export_seconds).sum())
        app = create_app(ServiceSettings(db_path=Path(folder) / "bench.db"), bus=None, store=store)
        with TestClient(app, base_url="http://127.0.0.1") as client:  # a loopback API answers loopback names only
            for fmt in ("mcap", "csv", "json"):
                params = {"format": fmt, "t1": export_seconds}
                url = f"/executions/{execution.id}/telemetry"
                elapsed, response = median_time(lambda params=params, url=url: client.get(url, params=params), repeats)
                assert response.status_code == 200, response.text
                measured[fmt] = (elapsed, len(response.content))
                rows.append(f"| {fmt} | {samples} | {len(response.content) / 1e6:.2f} | "
                            f"{len(response.content) / samples:.0f} | {elapsed:.2f} |")  # fmt: skip
        store.close()
    return rows, measured


def build_report(repeats: int, bag_seconds: float, export_seconds: float, move_duration_s: float | None) -> str:
    import os

    load = os.getloadavg()[0]
    imports, import_s = import_rows(repeats, bag_seconds)
    exports, export_measured = export_rows(repeats, export_seconds, move_duration_s)
    mcap_s, mcap_bytes = export_measured["mcap"]
    sentences = [
        f"A {bag_seconds:.0f} s bag at 1 kHz imports in {import_s['mcap']:.1f} s from MCAP and "
        f"{import_s['sqlite3']:.1f} s from sqlite3 (median of {repeats}).",
        f"A {export_seconds:g} s execution exports as MCAP in {mcap_s:.1f} s ({mcap_bytes / 1e6:.1f} MB, "
        f"{np.round(mcap_bytes / export_measured['json'][1], 2)} of its JSON).",
    ]
    return report_text([
        "## ROS 2 bag import, MCAP/CSV/JSON export",
        "",
        f"Command: `{COMMAND}`. Import: a {bag_seconds:.0f} s demonstration as a ROS 2 bag written by `rosbags`, "
        "WrenchStamped and PoseStamped at 1 kHz each, imported with `contact-skills learn`'s importer (read, align "
        f"on one time base, tare, validate). Export: the first {export_seconds:g} s of a real PyBullet execution's "
        f"stored telemetry (1 kHz) through `GET /executions/{{id}}/telemetry?format=...&t1={export_seconds:g}` "
        f"(in-process app). Medians of {repeats} runs.",
        "",
        "| bag storage | messages | MB | samples imported | import s | k messages / s |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
        *imports,
        "",
        "| format | samples | MB | bytes / sample | export s |",
        "| --- | ---: | ---: | ---: | ---: |",
        *exports,
        "",
        *sentences,
    ], load_at_start=load)  # fmt: skip


OPTIONS = [
    ("--repeats", {"type": int, "default": 3, "help": "runs per measurement (median)"}),
    ("--bag-seconds", {"type": float, "default": BAG_SECONDS, "help": "length of the imported bag, s"}),
    ("--export-seconds", {"type": float, "default": EXPORT_SECONDS, "help": "telemetry exported, s"}),
    ("--move-duration-s", {"type": float, "help": "the executed skill's stroke, s (default: the teacher's)"}),
]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {"repeats": 1, "bag_seconds": 5.0, "export_seconds": 2.0, "move_duration_s": 1.0}
"""The smoke run's values of the options."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
