"""The pure-MuJoCo lift scene, written by hand: no robosuite, no mesh files, one MJCF string.

A 6-joint capsule arm (yaw, shoulder, elbow, forearm roll, wrist pitch, wrist roll: a spherical
wrist, so any pose in the workspace is reachable) stands on a pedestal behind a table whose top
centre is (0, 0, TABLE_TOP_Z). Each arm joint has two actuators that together make a joint-velocity
servo: an ``intvelocity`` (ctrl = velocity, integrated into a position set point) and a
``velocity`` feed-forward, so a constant command is tracked without lag. The gripper's two slide
fingers are position-controlled; ``ee_site`` sits between the finger pads with its z axis along
the approach direction (out of the palm).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable

import numpy as np

from crowdteleop.errors import ConfigError

TIMESTEP = 0.002
TABLE_TOP_Z = 0.8
TABLE_HALF = 0.4
ROBOT_BASE_POS = (-0.5, 0.0, TABLE_TOP_Z)
CUBE_HALF = 0.0225
ARM_JOINTS = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6")
FINGER_JOINTS = ("finger_left", "finger_right")
FINGER_PADS = ("left_pad", "right_pad")
FINGER_TRAVEL = 0.045  # m per finger: 0 open (10 cm between pads), FINGER_TRAVEL closed
# ee_site at (-0.1, 0, 1.0), 0.2 m above the table, pointing straight down (analytic IK).
HOME_QPOS = (0.0, 0.2130, 2.0201, 0.0, 0.9085, 0.0)

# name, axis, range (rad), servo kp, velocity kv, damping: big joints stiff, wrist light.
_JOINTS = (
    ("joint1", "0 0 1", (-2.9, 2.9), 2000.0, 120.0, 2.0),
    ("joint2", "0 1 0", (-2.0, 2.0), 2000.0, 120.0, 2.0),
    ("joint3", "0 1 0", (-0.3, 2.8), 1200.0, 60.0, 1.0),
    ("joint4", "0 0 1", (-2.9, 2.9), 300.0, 10.0, 0.5),
    ("joint5", "0 1 0", (-2.2, 2.2), 300.0, 10.0, 0.5),
    ("joint6", "0 0 1", (-2.9, 2.9), 200.0, 6.0, 0.5),
)


def _look_at(position: tuple[float, float, float], target: tuple[float, float, float]) -> str:
    """``xyaxes`` of a camera at `position` looking at `target` with world z up."""
    forward = np.subtract(target, position)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return " ".join(f"{v:.4f}" for v in (*right, *up))


def _camera(
    name: str,
    position: tuple[float, float, float],
    target: tuple[float, float, float],
    fovy: float = 45.0,
) -> str:
    pos = " ".join(f"{v:g}" for v in position)
    axes = _look_at(position, target)
    return f'<camera name="{name}" pos="{pos}" xyaxes="{axes}" fovy="{fovy:g}"/>'


def _actuators() -> str:
    servo, feed_forward = [], []
    for name, _, (low, high), kp, kv, _ in _JOINTS:
        servo.append(
            f'<intvelocity name="{name}_servo" joint="{name}" kp="{kp:g}" '
            f'actrange="{low:g} {high:g}"/>'
        )
        feed_forward.append(f'<velocity name="{name}_velocity" joint="{name}" kv="{kv:g}"/>')
    fingers = [
        f'<position name="{j}_position" joint="{j}" kp="400" dampratio="1" '
        f'ctrlrange="0 {FINGER_TRAVEL}" forcerange="-20 20"/>'
        for j in FINGER_JOINTS
    ]
    return "\n    ".join(servo + feed_forward + fingers)


def _joint(index: int) -> str:
    name, axis, (low, high), _, _, damping = _JOINTS[index]
    return (
        f'<joint name="{name}" axis="{axis}" range="{low:g} {high:g}" damping="{damping:g}" '
        'armature="0.05"/>'
    )


def _finger(side: str, sign: int) -> str:
    """A finger sliding along the hand's y axis; positive joint values close it."""
    return f"""
              <body name="{side}_finger" pos="0 0 0.035" gravcomp="1">
                <joint name="finger_{side}" type="slide" axis="0 {-sign} 0"
                       range="0 {FINGER_TRAVEL}" damping="1" armature="0.05"/>
                <geom class="robot" type="box" pos="0 {sign * 0.06} 0.035" size="0.012 0.006 0.035"
                      material="gripper"/>
                <geom name="{side}_pad" class="robot" type="box" pos="0 {sign * 0.051} 0.05"
                      size="0.011 0.003 0.02" friction="1.5 0.01 0.001" condim="4"
                      material="pad"/>
              </body>"""


def lift_scene_xml() -> str:
    """The lift task: the arm, a table and a red 4.5 cm cube on it."""
    return _scene("crowdteleop_lift", _cube())


def objects_scene_xml(objects_mjcf: str, name: str) -> tuple[str, list[str]]:
    """The arm and the table with a task's own objects: the ``<worldbody>`` bodies and the
    ``<asset>`` entries of `objects_mjcf` (an MJCF document); and those bodies' names."""
    try:
        root = ET.fromstring(objects_mjcf)
    except ET.ParseError as error:
        raise ConfigError(f"the task's scene is not MJCF: {error}") from None
    worldbody = root.find("worldbody")
    bodies = [] if worldbody is None else worldbody.findall("body")
    names = [body.get("name", "") for body in bodies]
    if not bodies or not all(names):
        raise ConfigError("the task's scene needs named <body> elements in its <worldbody>")
    assets = root.find("asset")
    extra = "" if assets is None else "".join(ET.tostring(a, encoding="unicode") for a in assets)
    objects = "".join(ET.tostring(body, encoding="unicode") for body in bodies)
    return _scene(f"crowdteleop_{name}", objects, extra), names


def _scene(model: str, objects: str, extra_assets: str = "") -> str:
    cameras = "\n    ".join(
        (
            _camera("frontview", (1.6, 0.0, 1.45), (-0.15, 0.0, 0.95)),
            _camera("agentview", (0.55, 0.0, 1.45), (-0.12, 0.0, 0.82), fovy=55.0),
            _camera("sideview", (-0.1, 1.5, 1.45), (-0.1, 0.0, 0.95)),
        )
    )
    assets = _settings_and_assets()
    if extra_assets:
        assets = assets.replace("  </asset>", f"    {extra_assets}\n  </asset>")
    return f"""<mujoco model="{model}">
{assets}  <worldbody>
    <light name="key" directional="true" pos="0.5 0.5 3" dir="-0.2 -0.2 -1" diffuse="0.6 0.6 0.6"
           castshadow="true"/>
    <light name="fill" directional="true" pos="-1 -1 3" dir="0.3 0.3 -1" diffuse="0.25 0.25 0.25"
           castshadow="false"/>
    <geom name="floor" type="plane" size="3 3 0.05" material="floor"/>
{_table()}    {cameras}
{_arm()}{objects}  </worldbody>
  <actuator>
    {_actuators()}
  </actuator>
</mujoco>
"""


def _settings_and_assets() -> str:
    """Physics and look: the solver, lights' quality, textures, materials, geom classes."""
    return f"""  <compiler angle="radian" autolimits="true"/>
  <option timestep="{TIMESTEP}" integrator="implicitfast" cone="elliptic" impratio="10"/>
  <visual>
    <headlight ambient="0.3 0.3 0.3" diffuse="0.4 0.4 0.4" specular="0.1 0.1 0.1"/>
    <quality shadowsize="1024"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.7 0.9" rgb2="0.1 0.12 0.18"
             width="256" height="256"/>
    <texture name="checker" type="2d" builtin="checker" rgb1="0.32 0.36 0.42"
             rgb2="0.2 0.23 0.28" width="256" height="256"/>
    <material name="floor" texture="checker" texrepeat="6 6" texuniform="true"/>
    <material name="table" rgba="0.62 0.47 0.33 1"/>
    <material name="leg" rgba="0.35 0.27 0.2 1"/>
    <material name="link" rgba="0.85 0.86 0.88 1" specular="0.4"/>
    <material name="joint" rgba="0.25 0.27 0.3 1"/>
    <material name="gripper" rgba="0.18 0.18 0.2 1"/>
    <material name="pad" rgba="0.9 0.55 0.1 1"/>
    <material name="cube" rgba="0.85 0.1 0.1 1"/>
  </asset>
  <default>
    <geom friction="1 0.005 0.0001"/>
    <default class="robot">
      <geom contype="2" conaffinity="1"/>
      <default class="link">
        <geom type="capsule" material="link"/>
      </default>
    </default>
    <default class="visual">
      <geom type="cylinder" contype="0" conaffinity="0" group="1"/>
      <default class="joint_cap">
        <geom material="joint"/>
      </default>
      <default class="leg">
        <geom size="0.025 0.3875" material="leg"/>
      </default>
    </default>
  </default>
"""


def _table() -> str:
    return f"""    <body name="table" pos="0 0 0">
      <geom name="table_top" type="box" pos="0 0 {TABLE_TOP_Z - 0.025:g}"
            size="{TABLE_HALF} {TABLE_HALF} 0.025" material="table"/>
      <geom class="leg" pos="0.35 0.35 0.3875"/>
      <geom class="leg" pos="0.35 -0.35 0.3875"/>
      <geom class="leg" pos="-0.35 0.35 0.3875"/>
      <geom class="leg" pos="-0.35 -0.35 0.3875"/>
    </body>
"""


def _arm() -> str:
    """The six-joint arm on its base, with the two-finger hand (`ee_site` at its tip)."""
    bx, by, bz = ROBOT_BASE_POS
    return f"""    <body name="robot_base" pos="{bx:g} {by:g} {bz:g}">
      <geom class="robot" type="cylinder" pos="0 0 {-bz / 2:g}" size="0.09 {bz / 2:g}"
            material="joint"/>
      <geom class="robot" type="cylinder" pos="0 0 0.03" size="0.08 0.03" material="link"/>
      <body name="link1" pos="0 0 0.06" gravcomp="1">
        {_joint(0)}
        <geom class="link" fromto="0 0 0 0 0 0.14" size="0.06"/>
        <body name="link2" pos="0 0 0.16" gravcomp="1">
          {_joint(1)}
          <geom class="joint_cap" fromto="0 -0.07 0 0 0.07 0" size="0.062"/>
          <geom class="link" fromto="0 0 0 0 0 0.4" size="0.05"/>
          <body name="link3" pos="0 0 0.4" gravcomp="1">
            {_joint(2)}
            <geom class="joint_cap" fromto="0 -0.06 0 0 0.06 0" size="0.052"/>
            <geom class="link" fromto="0 0 0 0 0 0.19" size="0.04"/>
            <body name="link4" pos="0 0 0.2" gravcomp="1">
              {_joint(3)}
              <geom class="link" fromto="0 0 0 0 0 0.19" size="0.038"/>
              <body name="link5" pos="0 0 0.2" gravcomp="1">
                {_joint(4)}
                <geom class="joint_cap" fromto="0 -0.045 0 0 0.045 0" size="0.042"/>
                <geom class="link" fromto="0 0 0 0 0 0.06" size="0.035"/>
                <body name="hand" pos="0 0 0.08" gravcomp="1">
                  {_joint(5)}
                  <geom class="robot" type="cylinder" size="0.04 0.01" material="joint"/>
                  <geom class="robot" type="box" pos="0 0 0.02" size="0.03 0.075 0.015"
                        material="gripper"/>
                  <site name="ee_site" pos="0 0 0.085" size="0.006" rgba="0 1 0 0.6" group="3"/>
                  {_finger("left", 1)}
                  {_finger("right", -1)}
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
"""


def _cube() -> str:
    return f"""    <body name="cube" pos="0 0 {TABLE_TOP_Z + CUBE_HALF:g}">
      <freejoint name="cube_joint"/>
      <geom name="cube" type="box" size="{CUBE_HALF} {CUBE_HALF} {CUBE_HALF}" material="cube"
            density="1000" friction="1.2 0.01 0.001" condim="4"/>
    </body>
"""


SCENES: dict[str, Callable[[], str]] = {"lift": lift_scene_xml}


def scene_xml(name: str) -> str:
    """The MJCF of the scene a mujoco-backend task names in its registry entry."""
    try:
        return SCENES[name]()
    except KeyError:
        raise ConfigError(
            f"the mujoco backend has no scene {name!r}; it has: {', '.join(SCENES)}"
        ) from None
