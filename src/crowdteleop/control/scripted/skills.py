"""Synthetic workers of known skill: three `OperatorStyle`s a bot or a benchmark names.

A crowd's demonstrations range from a practised operator's to a first-timer's; data filters,
quality scores and reviewer tools are tested on workers whose skill is known in advance.

- **expert**: a practised operator: the steady default operator, a little faster (0.3 m/s),
  no tremor, no pauses, no slips.
- **intermediate**: 0.2 m/s, 2 mm tremor, reacts in 0.3 s, hesitates (0.2-1 s) at one
  waypoint in five, overshoots one waypoint in three by 10 % and corrects, idles 1-3 s at one
  waypoint in twenty, chatters the gripper on one grasp in five, drops nothing.
- **novice**: 0.15 m/s and slower turns, 5 mm tremor, reacts in 0.6 s, hesitates at one
  waypoint in three, overshoots every waypoint by 25 % and corrects, idles 3-10 s at one
  waypoint in seven, chatters the gripper on every other grasp, drops what it carries one leg
  in ten.

docs/quality.md ("Synthetic workers of known skill") has the table and the figures measured
with them.
"""

from __future__ import annotations

from crowdteleop.control.scripted.operator import OperatorStyle
from crowdteleop.vocab import InjectedFault, SkillName

SKILLS: dict[SkillName, OperatorStyle] = {
    "expert": OperatorStyle(speed_m_s=0.3),
    "intermediate": OperatorStyle(
        speed_m_s=0.2,
        tremor_m=0.002,
        reaction_s=0.3,
        hesitation_probability=0.2,
        overshoot_fraction=0.1,
        overshoot_probability=0.33,
        idle_probability=0.05,
        idle_s=(1.0, 3.0),
        hesitant_grasp_probability=0.2,
    ),
    "novice": OperatorStyle(
        speed_m_s=0.15,
        turn_rad_s=1.0,
        tremor_m=0.005,
        reaction_s=0.6,
        hesitation_probability=0.33,
        overshoot_fraction=0.25,
        idle_probability=0.15,
        idle_s=(3.0, 10.0),
        hesitant_grasp_probability=0.5,
        drop_probability=0.1,
    ),
}


# The faults a synthetic worker can be told to make, as changes to its style: each happens once
# per demonstration, and each should raise the quality flag named in docs/quality.md.
FAULTS: dict[InjectedFault, dict[str, float | bool]] = {
    "idle": {"grasp_idle_s": 10.0},  # flag longest_pause_s: "idle 10 s in the 'grasp' stage"
    "detour": {"detour_m": 0.4},  # flag path_ratio: "a detour: the hand travelled ..."
    "drop": {"drop_once": True},  # flag setbacks: "went back a stage (...)"
    "press": {"press_m": 0.1},  # flag table_contact_s: "pressed into the table ..."
}


def style_for(skill: SkillName | None, fault: InjectedFault | None = None) -> OperatorStyle | None:
    """The style of `skill` (with `fault` injected); None (the default operator) without
    either."""
    if skill is None and fault is None:
        return None
    style = SKILLS[skill] if skill is not None else OperatorStyle()
    return style if fault is None else style.model_copy(update=FAULTS[fault])
