"""Small edits of MJCF text that several parts of the platform need."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence


def with_arena(xml: str, memory: str) -> str:
    """The same model with its constraint arena set to `memory` (e.g. "16M").

    robosuite asks for njmax = nconmax = 5000, which MuJoCo turns into ~0.7 GiB per MjData;
    a scene of a few objects uses well under 10 MiB, and a kinematics-only copy needs ~none.
    """
    root = ET.fromstring(xml)
    size = root.find("size")
    if size is None:
        size = ET.SubElement(root, "size")
    for attribute in ("njmax", "nconmax", "nstack"):
        size.attrib.pop(attribute, None)
    size.set("memory", memory)
    return ET.tostring(root, encoding="unicode")


def kinematics_only(xml: str) -> str:
    """The same bodies, joints and sites without what only a picture needs: textures,
    materials and visual meshes (robosuite's geom group 1) go, and the arena shrinks.

    An IK solver's private copy of a robosuite scene drops from ~77 MiB to well under 1 MiB.
    """
    root = ET.fromstring(xml)
    asset = root.find("asset")
    for parent in root.iter():
        for geom in parent.findall("geom"):
            geom.attrib.pop("material", None)
            if geom.get("group") == "1" and geom.get("type") == "mesh":
                parent.remove(geom)
    if asset is not None:
        used_meshes = {geom.get("mesh") for geom in root.iter("geom")}
        for element in list(asset):
            unused_mesh = element.tag == "mesh" and element.get("name") not in used_meshes
            if element.tag in ("texture", "material") or unused_mesh:
                asset.remove(element)
    return with_arena(ET.tostring(root, encoding="unicode"), "1M")


def without_free_joints(xml: str) -> str:
    """The same model with its free joints removed: free bodies (a task's objects) stay fixed
    where the MJCF puts them.

    An arm's IK needs only the arm: every free object adds six unknowns to its QP (a pick-place
    scene 24 of 33) that no task term couples to the arm, so dropping them changes no answer.
    """
    root = ET.fromstring(xml)
    for body in root.iter("body"):
        for joint in [*body.findall("freejoint"), *body.findall("joint")]:
            if joint.tag == "freejoint" or joint.get("type") == "free":
                body.remove(joint)
    return ET.tostring(root, encoding="unicode")


_ASSET_FILE = re.compile(r'(\bfile=")[^"]*/site-packages/')


def portable(xml: str) -> str:
    """The model with each asset path cut to where it lies inside its installed package
    (``robosuite/models/assets/...``): the same scene recorded on one machine or venv and
    rebuilt on another then compares equal, as robosuite's own ``edit_model_xml`` rewrites a
    recorded ``model_file``'s paths to the local install before loading it."""
    return _ASSET_FILE.sub(r"\1", xml)


_BODY_TAG = re.compile(r"<body\b[^>]*>")
_PLACEMENT = re.compile(r'\s(?:pos|quat|euler|axisangle|xyaxes|zaxis)="[^"]*"')


def with_body_placements(
    xml: str, placements: Mapping[str, tuple[Sequence[float], Sequence[float]]]
) -> str:
    """The same model with the named bodies at (position, quaternion wxyz) in their parents:
    where a reset placed them (robosuite places fixtures such as Door's door in the model, not
    the state, so a recorded model file must carry them to rebuild the episode's scene).

    Edited as text, tag by tag: everything else in the file stays as it was written."""

    def placed(match: re.Match[str]) -> str:
        tag = match.group(0)
        name = re.search(r'\sname="([^"]*)"', tag)
        if name is None or name.group(1) not in placements:
            return tag
        position, quaternion = placements[name.group(1)]
        where = " ".join(f"{v:.12g}" for v in position)
        turn = " ".join(f"{v:.12g}" for v in quaternion)
        return f'<body pos="{where}" quat="{turn}"' + _PLACEMENT.sub("", tag)[len("<body") :]

    return _BODY_TAG.sub(placed, xml)


def _placement_free(xml: str) -> str:
    return _BODY_TAG.sub(lambda match: _PLACEMENT.sub("", match.group(0)), xml)


def same_model(recorded: str, rebuilt: str) -> bool:
    """Whether a rebuilt scene is the one a recording names, wherever each was installed and
    wherever its episode's reset placed the bodies (`with_body_placements`)."""
    if recorded == rebuilt or portable(recorded) == portable(rebuilt):
        return True
    return _placement_free(portable(recorded)) == _placement_free(portable(rebuilt))
