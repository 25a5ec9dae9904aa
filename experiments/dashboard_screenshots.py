"""The dashboard's screenshots in docs/DASHBOARD.md, taken with headless Chromium from a running stack (``make run``):
a skill's page, an execution followed live while the tool presses, a sweep's page.

    .venv/bin/python -m experiments.dashboard_screenshots [--out docs/figures]

It records ``slide_flat`` with the scripted teacher, learns it, runs it paced in real time with the table 1 cm higher
than taught (the controller not told) and shoots the execution's page 8 s in (in contact) and the skill's page after
it (which then shows the world that run used), then runs a 4-trial sweep of two controllers over an unknown height and
tilt and shoots its page. The service is the one ``$CONTACT_SKILLS_URL`` names (default http://127.0.0.1:8000).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from schemas.execution import ControllerKind, Pace
from schemas.sweep import SweepParameter
from services.client import Client
from services.dashboard.browser import headless_chromium

VIEWPORT = (1500, 1000)
"""The browser window, px: the pages' two columns side by side."""
PRESSING_S = 8.0
"""When the live page is shot, s of execution time: the tool presses (contact starts at about 4.5 s)."""


def take(out: Path) -> list[Path]:
    """Record, learn, execute and sweep on the running stack; the three screenshots written into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    shots = [out / f"dashboard_{name}.png" for name in ("live", "skill", "sweep")]
    with Client() as client, headless_chromium(VIEWPORT) as browser:
        url = client.url.rstrip("/")
        skill = client.learn(client.record("slide_flat", seed=0).id, skill_type="auto")
        execution = client.execute(skill.id, pace=Pace.realtime, unknown_offset=[0.0, 0.0, 0.01])
        page = browser.new_page()
        page.goto(f"{url}/#/execution/{execution.id}")
        page.wait_for_function(
            f"Number(document.querySelector('canvas.live-force')?.dataset.lastT) > {PRESSING_S}", timeout=120_000
        )
        page.wait_for_selector(".live-scene[data-work-piece][data-robot='1']", timeout=30_000)
        page.wait_for_timeout(500)  # the frame after the last event
        page.screenshot(path=shots[0], full_page=True)
        execution.wait()
        page.goto(f"{url}/#/skill/{skill.id}")
        page.wait_for_selector("#skill-scene[data-robot='1'][data-work-piece]", timeout=30_000)
        page.wait_for_timeout(500)
        page.screenshot(path=shots[1], full_page=True)
        height, tilt = SweepParameter.offset_z_m, SweepParameter.tilt_x_deg
        vary = {height: {"low": -0.01, "high": 0.01}, tilt: {"low": -5.0, "high": 5.0}}
        controllers = [ControllerKind.hybrid_cf, ControllerKind.impedance]
        sweep = client.run_sweep(skill.id, trials=4, controllers=controllers, vary=vary)
        sweep.wait()
        page.goto(f"{url}/#/sweep/{sweep.id}")
        page.wait_for_function("document.getElementById('sweep-figure')?.naturalWidth > 0", timeout=60_000)
        page.screenshot(path=shots[2], full_page=True)
    return shots


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures"), help="folder of the PNGs")
    for shot in take(parser.parse_args().out):
        print(f"wrote {shot}")


if __name__ == "__main__":
    main()
