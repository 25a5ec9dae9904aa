"""The contract rejects every class of bad input with a message naming the field and the reason."""

import math

import numpy as np
import pytest
from pydantic import ValidationError

from corpus import synthetic
from schemas import Demonstration, LearnOptions
from schemas.demonstration import MIN_DEMONSTRATION_SAMPLES


def valid_body(n: int = 100) -> dict:
    demo = synthetic.plane_slide(duration_s=n / 1000.0 + 1e-9)
    return {
        "t": demo.t[:n].tolist(),
        "positions": demo.positions[:n].tolist(),
        "orientations": demo.orientations[:n].tolist(),
        "wrenches": demo.wrenches[:n].tolist(),
    }


def error_of(body: dict) -> tuple[tuple, str]:
    with pytest.raises(ValidationError) as raised:
        Demonstration.model_validate(body)
    first = raised.value.errors()[0]
    return first["loc"], first["msg"]


def test_valid_body_is_accepted_and_round_trips_losslessly() -> None:
    demonstration = Demonstration.model_validate(valid_body())
    assert Demonstration.model_validate_json(demonstration.model_dump_json()) == demonstration


@pytest.mark.parametrize("field", ["positions", "wrenches", "orientations", "t"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_values_name_the_field_and_row(field: str, bad: float) -> None:
    body = valid_body()
    if field == "t":
        body["t"][17] = bad
    else:
        body[field][17][0] = bad
    loc, message = error_of(body)
    assert loc[0] == field
    assert "17" in message or "finite" in message.lower()


def test_length_mismatch_names_both_fields() -> None:
    body = valid_body()
    body["wrenches"] = body["wrenches"][:-3]
    _, message = error_of(body)
    assert "wrenches" in message and "t has 100" in message


def test_row_of_the_wrong_width_names_the_row() -> None:
    body = valid_body()
    body["positions"][5] = [0.0, 1.0]
    loc, message = error_of(body)
    assert loc[:2] == ("positions", 5)
    assert "3" in message


def test_non_increasing_time_names_the_sample() -> None:
    body = valid_body()
    body["t"][40] = body["t"][39]
    loc, message = error_of(body)
    assert loc == ("t",)
    assert "strictly increasing" in message and "sample 40" in message


def test_non_unit_quaternion_is_refused_and_near_unit_is_normalized() -> None:
    body = valid_body()
    body["orientations"][9] = [0.0, 0.0, 0.0, 2.0]
    loc, message = error_of(body)
    assert loc == ("orientations",) and "sample 9" in message and "norm 2" in message
    body["orientations"][9] = [0.0, 0.0, 0.0, 1.004]
    demonstration = Demonstration.model_validate(body)
    assert np.linalg.norm(demonstration.orientations[9]) == pytest.approx(1.0)


def test_too_few_samples_and_empty_arrays_are_refused() -> None:
    loc, message = error_of(valid_body(MIN_DEMONSTRATION_SAMPLES - 1))
    assert loc == ("t",) and f"at least {MIN_DEMONSTRATION_SAMPLES}" in message
    empty = {"t": [], "positions": [], "orientations": [], "wrenches": []}
    loc, _ = error_of(empty)
    assert loc == ("t",)


def test_unknown_fields_and_skill_types_are_refused() -> None:
    body = valid_body()
    body["forces"] = body.pop("wrenches")
    with pytest.raises(ValidationError):
        Demonstration.model_validate(body)
    with pytest.raises(ValidationError) as raised:
        LearnOptions.model_validate({"skill_type": "polish"})
    assert raised.value.errors()[0]["loc"] == ("skill_type",)
