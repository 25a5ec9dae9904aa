"""The simulated robot: a KUKA LBR iiwa 14 (PyBullet's model) with a ball-tipped tool on a fixed joint.

Tool and tool point
    A rigid tool is part of the robot URDF, built at run time: a shaft (radius 8 mm, 70 mm long)
    on the iiwa flange (45 mm beyond the link-7 frame) ending in a ball of radius
    ``ToolConfig.radius_m`` (10 mm). It is a separate link (``tool_link``, index 7) on a FIXED
    joint, so it has an exact link frame and Jacobian. The TOOL POINT (the origin of that link frame)
    is the ball's lowest point along the tool axis, i.e. ball centre + radius along the tool's z axis,
    125 mm from the link-7 frame. The tool frame's z axis points out of the flange, along the tool:
    when the tool is held perpendicular to a surface, the tool point is the contact point and the tool
    z axis points INTO the surface, along the force the tool applies (like the compliant frame).

Conventions: docs/CONVENTIONS.md (SI units, quaternions ``[x, y, z, w]``).
"""

from __future__ import annotations

import os

import pybullet_data

from schemas.world import ToolConfig

N_JOINTS = 7
TOOL_LINK = 7
"""Link index of the tool (fixed joint on link 7); its frame origin is the tool point."""

FLANGE_OFFSET_M = 0.045
"""Distance of the iiwa flange from the link-7 frame along its z axis (the link-7 mesh ends there)."""

Q_HOME = (0.0, 0.5325, 0.0, -1.6083, 0.0, 1.0008, 0.0)


def robot_urdf(tool: ToolConfig) -> str:
    """The iiwa URDF with absolute mesh paths and the ``tool`` link (m, kg) appended on a fixed joint."""
    data = pybullet_data.getDataPath()
    with open(os.path.join(data, "kuka_iiwa", "model.urdf"), encoding="utf-8") as handle:
        text = handle.read()
    text = text.replace('filename="meshes/', f'filename="{os.path.join(data, "kuka_iiwa", "meshes")}/')
    r = tool.radius_m
    L = tool.shaft_length_m
    rs = tool.shaft_radius_m
    m = tool.mass_kg
    tip = FLANGE_OFFSET_M + L + r  # link-7 frame to tool point
    com = -(0.5 * L + r)  # shaft centre in the tool frame
    ixx = m * (3 * rs * rs + L * L) / 12.0
    izz = 0.5 * m * rs * rs
    tool = f"""
  <joint name="tool_joint" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="tool_link"/>
    <origin rpy="0 0 0" xyz="0 0 {tip:.6f}"/>
  </joint>
  <link name="tool_link">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 {com:.6f}"/>
      <mass value="{m:.6f}"/>
      <inertia ixx="{ixx:.8f}" ixy="0" ixz="0" iyy="{ixx:.8f}" iyz="0" izz="{izz:.8f}"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {-(r + 0.5 * L):.6f}"/>
      <geometry><cylinder radius="{rs:.6f}" length="{L:.6f}"/></geometry>
      <material name="Grey"/>
    </visual>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {-r:.6f}"/>
      <geometry><sphere radius="{r:.6f}"/></geometry>
      <material name="Orange"/>
    </visual>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-(r + 0.5 * L):.6f}"/>
      <geometry><cylinder radius="{rs:.6f}" length="{L:.6f}"/></geometry>
    </collision>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-r:.6f}"/>
      <geometry><sphere radius="{r:.6f}"/></geometry>
    </collision>
  </link>
"""
    return text.replace("</robot>", tool + "</robot>")
