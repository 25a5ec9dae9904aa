"""The execution of a skill apart from any physics engine: the phase plans, the contact detection, the surface
following, the telemetry rows, the metrics and verdicts, and the robot interface an engine (or a real cell) offers
the control loop (:mod:`execution.robot`). Imports only ``schemas`` and ``skills`` (``tests/test_layers.py``)."""
