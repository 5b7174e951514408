"""Small edits of MJCF text that several parts of the platform need."""

from __future__ import annotations

import xml.etree.ElementTree as ET


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
