"""Several demonstrations learned together through the service (``POST /skills`` with ``demonstration_ids``), the
typed client and ``contact-skills learn a.csv b.csv c.csv``: the real API on 127.0.0.1, real learner processes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cli.main import main
from corpus.case import CorpusCase
from corpus.families import human_trials
from schemas.skill import MAX_JOINT_DEMONSTRATIONS, Skill
from services.api.routes import skills as skills_route

FORM = {"quaternion_order": "wxyz", "wrench": "measured-on-tool", "wrench_frame": "tool"}
"""How the corpus's human-like files are read (`corpus.case.CsvRecording.import_options`)."""
CLI_OPTIONS = ["--quaternion-order", "wxyz", "--wrench", "measured-on-tool", "--wrench-frame", "tool"]


@pytest.fixture(scope="module")
def trials() -> list[CorpusCase]:
    """Three trials of one straight stroke, and a contour across a cylinder 9 cm away (another task)."""
    return [*human_trials("human-straight", 0, 3), human_trials("human-cylinder", 0, 1)[0]]


def _upload(client, case: CorpusCase) -> str:
    files = {"file": (f"{case.name}.csv", case.recording.csv_text.encode(), "text/csv")}
    response = client.post("/demonstrations/csv", files=files, data=FORM | {"name": case.name})
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _locs(response) -> list[list]:
    return [entry["loc"] for entry in response.json()["detail"]]


def test_several_stored_demonstrations_learn_one_skill_naming_each(client, trials):
    ids = [_upload(client, case) for case in trials]
    learned = client.post("/skills", json={"demonstration_ids": ids})
    assert learned.status_code == 201, learned.text
    reply = learned.json()
    skill = Skill.model_validate(reply["skill"])
    uses = skill.demonstrations
    assert uses is not None and [use.source for use in uses] == ids
    assert [use.weight > 0 for use in uses] == [True, True, True, False]
    assert uses[3].misfit is not None and uses[3].reason
    reference = next(use for use in uses if use.reference)
    assert (
        reply["demonstration_id"] == reference.source == client.get(f"/skills/{reply['id']}").json()["demonstration_id"]
    )
    assert skill.skill_type.value == "slide" and all(
        s.force_band is not None for s in skill.segments if s.kind.value == "contact"
    )

    one = client.post("/skills", json={"demonstration_ids": ids[:1]}).json()["skill"]
    assert one == client.post("/skills", json={"demonstration_id": ids[0]}).json()["skill"]  # as one always did

    refused = client.post("/skills", json={"demonstration_ids": ids, "misfit": "refuse"})
    assert refused.status_code == 422 and _locs(refused) == [["body", "demonstration_ids"]]
    assert ids[3] in refused.json()["detail"][0]["msg"] and "does not fit" in refused.json()["detail"][0]["msg"]


def test_bad_demonstration_ids_are_422_naming_the_field(client, trials, monkeypatch):
    ids = [_upload(client, case) for case in trials[:2]]
    twice = client.post("/skills", json={"demonstration_ids": [ids[0], ids[0]]})
    assert twice.status_code == 422 and "given twice" in twice.text and "demonstration_ids" in twice.text
    many = client.post(
        "/skills", json={"demonstration_ids": [f"demo_{k}" for k in range(MAX_JOINT_DEMONSTRATIONS + 1)]}
    )
    assert many.status_code == 422 and ["body", "demonstration_ids"] in _locs(many)
    empty = client.post("/skills", json={"demonstration_ids": []})
    assert empty.status_code == 422 and ["body", "demonstration_ids"] in _locs(empty)
    both = client.post("/skills", json={"demonstration_ids": ids, "demonstration_id": ids[0]})
    assert both.status_code == 422 and "exactly one of" in both.text
    assert client.post("/skills", json={"demonstration_ids": [ids[0], "demo_unknown"]}).status_code == 404
    monkeypatch.setattr(skills_route, "MAX_JOINT_SAMPLES", 1000)  # two recordings of ~800 samples each
    over = client.post("/skills", json={"demonstration_ids": ids})
    assert over.status_code == 422 and _locs(over) == [["body", "demonstration_ids"]]
    assert "samples in all" in over.json()["detail"][0]["msg"]


def test_the_cli_learns_several_files_together_and_refuses_a_misfit_when_asked(tmp_path, trials, capsys):
    paths = []
    for case in trials:
        path = tmp_path / f"{case.name}.csv"
        path.write_text(case.recording.csv_text)
        paths.append(str(path))
    output = tmp_path / "skill.json"
    assert main(["learn", *paths[:3], *CLI_OPTIONS, "-o", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "learned from 3 of 3 demonstrations together" in printed
    skill = Skill.model_validate(json.loads(output.read_text()))
    assert [use.source for use in skill.demonstrations or []] == paths[:3]

    assert main(["learn", *paths, *CLI_OPTIONS, "--misfit", "refuse", "-o", str(tmp_path / "no.json")]) == 2
    refused = capsys.readouterr()
    assert Path(paths[3]).name in refused.err + refused.out and not (tmp_path / "no.json").exists()
