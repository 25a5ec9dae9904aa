"""``WorldConfig`` as typed sub-configs, and the worlds stored before them (one flat dict) still loading: a teacher
recording's world file, a skill's taught world, a bus payload's world overrides."""

from __future__ import annotations

import json

import numpy as np
import pytest

from schemas.world import (
    LEGACY_FIELDS,
    CylinderConfig,
    SensorConfig,
    SensorModel,
    TableConfig,
    WorkPiece,
    WorldConfig,
)
from sim_worker.execution_world import world_config_from_file_dict
from sim_worker.world import SimWorld

STORED_FLAT = json.loads(
    '{"time_step_s": 0.001, "gravity": [0.0, 0.0, -9.81], "table_enabled": true, "table_height_m": 0.12,'
    ' "table_center_xy": [0.6, 0.0], "table_size_xy": [0.6, 0.8], "table_thickness_m": 0.04, "table_tilt_deg": 15.0,'
    ' "table_tilt_axis": [1.0, 0.0, 0.0], "ramp_enabled": false, "ramp_tilt_deg": 20.0, "ramp_crease_x_m": 0.0,'
    ' "ramp_length_m": 0.2, "ramp_thickness_m": 0.04, "cylinder_enabled": true, "cylinder_radius_m": 0.07,'
    ' "cylinder_length_m": 0.3, "cylinder_xy_m": [0.0, 0.05], "cylinder_yaw_deg": 90.0,'
    ' "cylinder_offset_m": [0.0, 0.0, 0.08], "block_enabled": false, "block_half_length_m": 0.15,'
    ' "block_cap_height_m": 0.06, "block_base_height_m": 0.02, "block_width_m": 0.16, "block_xy_m": [0.0, 0.0],'
    ' "block_yaw_deg": 0.0, "block_offset_m": [0.0, 0.0, 0.0], "block_mesh_segments": 180,'
    ' "work_pieces": [{"name": "p", "vertices": [[0.5, -0.1, 0.0], [0.7, -0.1, 0.0], [0.5, 0.1, 0.0],'
    ' [0.5, -0.1, 0.05]], "layers": 2}], "contact_stiffness": 25000.0, "contact_damping": 250.0,'
    ' "lateral_friction": 0.3, "tool_radius_m": 0.012, "tool_shaft_length_m": 0.07, "tool_shaft_radius_m": 0.008,'
    ' "tool_mass_kg": 0.25, "torque_limits_nm": [320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0],'
    ' "sensor_model": "wrist", "wrench_noise_force_std_n": 0.06, "wrench_noise_torque_std_nm": 0.002,'
    ' "wrench_bias_drift_n_per_sqrt_s": 0.02, "wrench_delay_s": 0.002, "wrench_filter_cutoff_hz": 200.0,'
    ' "wrench_bias_n": [0.0, 0.0, 0.5], "wrench_offset_tool_n": [0.1, 0.0, 0.0], "seed": 7,'
    ' "work_piece_tilt_deg": [2.0, 0.0], "work_piece_tilt_pivot_m": [0.6, 0.0, 0.1]}'
)
"""A world as ``WorldConfig.to_dict`` wrote it before the sub-configs (every field, none at its default value where
it can differ), e.g. the ``world_config`` of a ``record --truth`` file."""


def test_a_world_stored_with_the_old_flat_keys_loads_every_field_into_its_sub_config() -> None:
    config = WorldConfig.from_dict(STORED_FLAT)
    assert set(STORED_FLAT) - {"time_step_s", "gravity", "work_pieces", "torque_limits_nm"} == set(LEGACY_FIELDS)
    for key, (part, name) in LEGACY_FIELDS.items():
        value = getattr(getattr(config, part), name)
        stored = STORED_FLAT[key]
        assert value == (tuple(stored) if isinstance(stored, list) else stored), key
    assert config.table == TableConfig(height_m=0.12, tilt_deg=15.0)
    assert config.sensor.model is SensorModel.wrist and config.sensor.seed == 7
    assert config.work_pieces == (
        WorkPiece(
            name="p", vertices=[[0.5, -0.1, 0.0], [0.7, -0.1, 0.0], [0.5, 0.1, 0.0], [0.5, -0.1, 0.05]], layers=2
        ),
    )
    assert WorldConfig.from_dict(config.to_dict()) == config  # the nested form round-trips
    assert "table_height_m" not in config.to_dict() and config.to_dict()["table"]["height_m"] == 0.12
    assert world_config_from_file_dict({"world_config": STORED_FLAT}) == config  # a ground-truth file's world


def test_flat_keys_and_sub_configs_give_the_same_world_and_the_same_simulation() -> None:
    """The constructor and ``replace`` take either form, also mixed (a flat key wins over its nested field); the two
    worlds built from them step identically."""
    nested = WorldConfig(
        table=TableConfig(height_m=0.08),
        cylinder=CylinderConfig(enabled=True, radius_m=0.06),
        sensor=SensorConfig(seed=3),
    )
    flat = WorldConfig(table_height_m=0.08, cylinder_enabled=True, cylinder_radius_m=0.06, seed=3)
    assert flat == nested
    assert WorldConfig().replace(table={"height_m": 0.08}).table == nested.table
    mixed = WorldConfig.from_dict({**nested.to_dict(), "cylinder_radius_m": 0.09})
    assert mixed.cylinder == CylinderConfig(enabled=True, radius_m=0.09)
    assert nested.replace(sensor_model="wrist").sensor == SensorConfig(model=SensorModel.wrist, seed=3)
    with SimWorld(nested) as a, SimWorld(flat) as b:
        for world in (a, b):
            for _ in range(100):
                world.step(world.gravity_coriolis_torques() + 0.5)
        np.testing.assert_array_equal(a.robot_state(), b.robot_state())


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"sensor_model": "strain"}, "sensor.model"),
        ({"sensor": {"model": "wrist", "delay": 0.1}}, "sensor.delay"),
        ({"table_colour": "red"}, "table_colour"),
        ({"work_pieces": [{"name": "p", "vertices": [[0, 0]]}]}, "work_pieces.0.vertices.0"),
        ({"work_pieces": [{"vertices": [[0, 0, 0]], "layers": 0}]}, "work_pieces.0.layers"),
    ],
)
def test_a_bad_world_is_refused_naming_the_field(data: dict, field: str) -> None:
    with pytest.raises(ValueError, match=f"world: WorldConfig: {field.replace('.', '[.]')}"):
        world_config_from_file_dict(data)
