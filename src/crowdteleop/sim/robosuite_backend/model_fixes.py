"""Corrections to robosuite's compiled models, applied as MJCF edits so saved XML carries them.

MuJoCo filters contacts between a body and its parent, except when the parent is welded to the
world. robosuite mounts each arm on a static base, so the first link rubs on the base: on Sawyer
the contact's friction holds joint 0 still (about 45 N m of the 80 N m it can apply). We exclude
those parent-child contacts explicitly.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco


def static_parent_pairs(model: mujoco.MjModel) -> list[tuple[str, str]]:
    """(parent, child) pairs MuJoCo's parent filter misses: jointed child, static parent."""
    pairs = []
    for body in range(1, model.nbody):
        parent = int(model.body_parentid[body])
        if parent != 0 and model.body_weldid[parent] == 0 and model.body_jntnum[body] > 0:
            pairs.append((model.body(parent).name, model.body(body).name))
    return pairs


def add_contact_excludes(xml: str, pairs: list[tuple[str, str]]) -> str:
    """The same MJCF with a `<contact><exclude/>` element per pair (existing ones kept)."""
    if not pairs:
        return xml
    root = ET.fromstring(xml)
    contact = root.find("contact")
    if contact is None:
        contact = ET.SubElement(root, "contact")
    present = {(e.get("body1"), e.get("body2")) for e in contact.findall("exclude")}
    for body1, body2 in pairs:
        if (body1, body2) not in present:
            ET.SubElement(contact, "exclude", body1=body1, body2=body2)
    return ET.tostring(root, encoding="unicode")
