"""The physics model our fast path steps: robosuite's model plus what lets the controller run
inside MuJoCo's C loop.

robosuite evaluates its Python controllers at every 2 ms substep (80% of its step time). We
evaluate them once per control step, linearized, and hand MuJoCo the result as actuators:

- gravity compensation as MuJoCo's native per-body ``gravcomp`` on the arm (exact at every
  substep); what it leaves out (fingers' weight, Coriolis) is held per control step;
- the controller's coupled joint stiffness K and damping D (K = sum l_k v_k v_k^T) as fixed
  tendons whose joint coefficients are the eigenvectors v_k, each driven by an affine actuator
  of gain l_k: tendon k pushes with l_k (v_k . q_ref - v_k . q), together -K (q - q_ref);
  damping tendons likewise give -D qdot. Coefficients and gains change every control step.

The additions create no joints, so states keep robosuite's [time, qpos, qvel] layout. The XML
saved with demonstrations is the one without them (see `RobosuiteSimulation.mjcf_xml`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence

from crowdteleop.sim.mjcf import with_arena

ARENA = "32M"  # a scene of a few objects uses < 10 MiB (see `with_arena`)

STIFFNESS_PREFIX = "ct_stiffness_"
DAMPING_PREFIX = "ct_damping_"


def _arm_bodies(root: ET.Element, robot_root: str, arm_joints: Sequence[str]) -> list[ET.Element]:
    """Bodies of the robot moved by arm joints only: fingers (on joints of their own) excluded,
    as robosuite compensates gravity on the arm's joints but not on the fingers'."""
    arm = set(arm_joints)

    def walk(body: ET.Element) -> list[ET.Element]:
        if any(joint.get("name") not in arm for joint in body.findall("joint")):
            return []
        found = [body]
        for child in body.findall("body"):
            found += walk(child)
        return found

    for body in root.iter("body"):
        if body.get("name") == robot_root:
            return walk(body)
    raise ValueError(f"body {robot_root!r} not found in the model")


def _park(root: ET.Element, body_names: Sequence[str]) -> None:
    """Objects a task does not use float where robosuite parks them, touching nothing.

    robosuite drops them at (10, 10, 10); they fall and jostle on the floor for ever, which
    costs contacts every substep and keeps the scene from ever coming to rest.
    """
    wanted = set(body_names)
    for body in root.iter("body"):
        if body.get("name") in wanted:
            for part in body.iter("body"):
                part.set("gravcomp", "1")
            for geom in body.iter("geom"):
                geom.set("contype", "0")
                geom.set("conaffinity", "0")


def fast_physics_xml(
    xml: str,
    robot_root_body: str,
    arm_joints: Sequence[str],
    parked_bodies: Sequence[str] = (),
) -> str:
    """`xml` plus gravity compensation on the robot, folded-controller tendons, parked unused
    objects and a sized arena."""
    root = ET.fromstring(xml)
    _park(root, parked_bodies)
    for body in _arm_bodies(root, robot_root_body, arm_joints):
        body.set("gravcomp", "1")

    tendon = root.find("tendon")
    if tendon is None:
        tendon = ET.SubElement(root, "tendon")
    actuator = root.find("actuator")
    if actuator is None:
        actuator = ET.SubElement(root, "actuator")
    for prefix in (STIFFNESS_PREFIX, DAMPING_PREFIX):
        for index in range(len(arm_joints)):
            name = f"{prefix}{index}"
            fixed = ET.SubElement(tendon, "fixed", name=name)
            for joint in arm_joints:
                ET.SubElement(fixed, "joint", joint=joint, coef="0")
            ET.SubElement(
                actuator,
                "general",
                name=name,
                tendon=name,
                gaintype="fixed",
                biastype="affine",
                gainprm="0",
                biasprm="0 0 0",
                ctrllimited="false",
            )
    return with_arena(ET.tostring(root, encoding="unicode"), ARENA)
