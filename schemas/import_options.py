"""The options of an import, spelled once: `ImportOptions` (every importer's), `CsvImportOptions` and
`BagImportOptions`.

The same models are the flags of ``contact-skills learn FILE`` (``cli/import_options.py`` generates them), the form
fields of ``POST /demonstrations/csv`` and ``POST /demonstrations/bag``, and the argument of
``services.csv_import.demonstration_from_csv`` and ``services.bag_import.demonstration_from_bag``. A field's alias,
where it has one, is its name on the command line and in the form (``rate_hz`` is ``--rate`` and ``rate``); in Python
either name works. The models check types and closed sets; the importers check the values (a rate in range, a rate
and a dt that agree, an offset of 3 or 6 numbers, a window that holds samples), naming the option, so that every
interface gives their messages.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, JsonValue, model_validator

from schemas.demonstration import QuaternionOrder, WrenchConvention, WrenchFrame
from schemas.numbers import Real
from schemas.text import Name, Text

COLUMN_KEYS = ("t", "px", "py", "pz", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz")
"""Keys of a column spec: time (s); position (m); quaternion components; force (N); moment (N·m)."""

PLAUSIBLE_READINGS = "plausible_readings"
"""The key of a demonstration's ``metadata.extra`` (and of an upload answer's ``extra``) listing the other readings of
the recorded wrench its import note advises, each as import options (form names and values, e.g.
``{"wrench": "measured-on-tool"}``; ``services.import_steps``)."""

UPLOAD_FIELD = "file"
"""The multipart field of an upload route that carries the file itself (the route's own parameter)."""


def _numbers_from_text(value: Any) -> Any:
    """A form field's ``'a,b,c'`` or ``'[a, b, c]'`` (a JSON array as text; or a one-element list of either, as a
    multipart form delivers a list field) as a list of number strings; anything else unchanged. Blank text is
    None."""
    if isinstance(value, list) and len(value) == 1 and isinstance(value[0], str):
        value = value[0]
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("[") and text.endswith("]"):
            text = text[1:-1]
        return [part.strip() for part in text.split(",")] if text.strip() else None
    return value


def _file_in_the_form(schema: dict[str, JsonValue]) -> None:
    """The JSON schema says what the before-validator accepts: an upload form's ``file`` beside the options."""
    schema["properties"][UPLOAD_FIELD] = {"description": "The uploaded file (the route's own parameter)."}


class ImportOptions(BaseModel):
    """What every importer takes: how to read the recorded wrench, the time base, the sensor offset, the name."""

    model_config = ConfigDict(
        extra="forbid", validate_by_name=True, validate_by_alias=True, json_schema_extra=_file_in_the_form
    )

    wrench_convention: WrenchConvention = Field(
        WrenchConvention.applied_by_tool,
        alias="wrench",
        description="What the recorded wrench is: applied-by-tool (what the tool applies to the environment: kept) "
        "or measured-on-tool (a sensor's reaction, as most F/T drivers publish it: negated).",
    )
    wrench_frame: WrenchFrame | None = Field(
        None,
        description="Frame the recorded wrench is expressed in, at the tool point: world (kept) or tool (rotated "
        "into the world with each sample's tool orientation). Default: world for a CSV file (whose *_w or *_tcp "
        "columns it also prefers); for a bag, what the messages' header frame_id says (world, tool, or a sensor "
        "frame fixed on the tool by /tf_static), which this overrides.",
    )
    rate_hz: Real | None = Field(
        None,
        alias="rate",
        description="Rate of the demonstration's uniform time base, Hz (default: the data's own: the fastest "
        "channel group of a CSV log, the faster topic of a bag). For a CSV file WITHOUT a time column: the rate "
        "its rows were sampled at (t = row / rate from 0); rate or dt is then required.",
        examples=[100.0],
    )
    tare: bool = Field(
        True,
        description="Whether the wrist sensor's offset is removed, fitted in the sensor (tool) frame over every "
        "free-space stretch together with the hand's push on the arm and, where the tool was held in different "
        "orientations in the air, an uncompensated tool weight (default true; a recording with no free space "
        "keeps an unknown offset, and its skill's sensor_offset check fails); false (--no-tare on the command "
        "line) declares the file compensated and keeps the wrench as recorded.",
    )
    tare_window_s: Annotated[tuple[float, float] | None, BeforeValidator(_numbers_from_text)] = Field(
        None,
        alias="tare_window",
        description="T0, T1 in s from the first sample (a form field: 'T0,T1'): the sensor offset is instead the "
        "median of the recorded wrench in this window, where nothing touches the tool (in the file's own frame "
        "and sign).",
        examples=[[0.0, 0.8]],
    )
    force_offset: Annotated[tuple[float, ...] | None, BeforeValidator(_numbers_from_text)] = Field(
        None,
        description="FX, FY, FZ in N [and MX, MY, MZ in N·m] (a form field: 'FX,FY,FZ'): subtract this sensor "
        "offset instead, as the recording reads it with nothing touching the tool (its own frame and sign).",
        examples=[[0.4, -1.2, 2.0]],
    )
    name: Name | None = Field(None, description="Name of the demonstration (default: the file name, no suffix).")

    @model_validator(mode="before")
    @classmethod
    def _without_the_file(cls, data: Any) -> Any:
        """An upload form also carries the file (the route's own parameter): not an unknown option."""
        return {k: v for k, v in data.items() if k != UPLOAD_FIELD} if isinstance(data, dict) else data


class CsvImportOptions(ImportOptions):
    """The options of a CSV recording: which column is which, the quaternion order, the time step."""

    columns: Text | None = Field(
        None,
        description="Which header column holds which quantity, key=column pairs separated by commas (keys "
        f"{' '.join(COLUMN_KEYS)}); the keys not given are recognised from common header names.",
        examples=["t=time,px=tcp_x,qw=tcp_qw,fz=Fz"],
    )
    quaternion_order: QuaternionOrder | None = Field(
        None,
        description="Order of the quaternion columns in the file: xyzw (scalar last) or wxyz (scalar first); "
        "needed for numbered columns (q0..q3), else taken from the column names (qw, tcp_qw, ...).",
    )
    dt_s: Real | None = Field(
        None,
        alias="dt",
        description="Time step, s: the same as rate = 1/dt (the fixed step of a file without a time column); "
        "given with rate, the two must agree.",
        examples=[0.01],
    )


class BagImportOptions(ImportOptions):
    """The options of a ROS 1 or ROS 2 bag: which topics hold the wrench and the tool pose, and its frame."""

    wrench_topic: Name | None = Field(
        None, description="The geometry_msgs/msg/WrenchStamped topic (default: the bag's only one)."
    )
    pose_topic: Name | None = Field(
        None,
        description="The geometry_msgs/msg/PoseStamped topic of the tool pose (default: the bag's only one, "
        "else the one moving /tf pair).",
    )
    tf_parent: Name | None = Field(None, description="The tool pose from /tf instead: the world frame (with tf_child).")
    tf_child: Name | None = Field(None, description="The tool pose from /tf instead: the tool frame (with tf_parent).")
    tool_frame: Name | None = Field(
        None, description="The frame a PoseStamped is the pose of (a wrench in that frame is the tool's)."
    )

    @model_validator(mode="after")
    def _tf_pair(self) -> BagImportOptions:
        if (self.tf_parent is None) != (self.tf_child is None):
            raise ValueError("tf_parent and tf_child name the /tf pair together: give both or neither")
        return self

    @property
    def tf_frames(self) -> tuple[str, str] | None:
        """The ``/tf`` pair (world, tool) the tool pose comes from, if given."""
        return None if self.tf_parent is None or self.tf_child is None else (self.tf_parent, self.tf_child)


__all__ = ["COLUMN_KEYS", "PLAUSIBLE_READINGS", "BagImportOptions", "CsvImportOptions", "ImportOptions"]
