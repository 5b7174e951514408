"""``crowdteleop dataset check FILE``: will the field's own tools accept this dataset as it is?

Each check does what a robosuite, robomimic or LeRobot user's code does with the file and says
pass, fail or skip, with the figure behind the verdict:

- ``env_info``: robosuite's playback script rebuilds each demo (``robosuite.make(**env_info)``,
  ``reset_from_xml_string(edit_model_xml(model_file))``);
- ``states``: those states set one by one read back exactly;
- ``actions``: the recorded actions stepped in plain robosuite built from ``env_args`` (the
  controller it names) move the hand where it went, step by step (bounded) and open loop
  (reported after 20 and 40 steps: delta actions compound);
- ``actions_abs``: the absolute targets stepped open loop in robosuite's absolute OSC;
- ``scene from env_args``: in what a policy rollout builds (``robosuite.make(env_name,
  **env_kwargs)``, no ``model_file``) no contact the demos' model excludes touches at the
  demos' states (robosuite's Sawyer keeps its base contact, and joint 0 sticks: docs/dataset.md);
- ``obs``: the low-dim keys robomimic's stock configs ask for, with robosuite's shapes, in
  ``obs/`` and ``next_obs/``, and robomimic's ``SequenceDataset`` loading them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import h5py
import numpy as np

from crowdteleop.dataset.files import open_dataset
from crowdteleop.provenance.controllers import CompositeController
from crowdteleop.provenance.env_args import EnvArgs

Verdict = Literal["pass", "fail", "skip"]
STOCK_LOW_DIM = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")
STOCK_SHAPES = {"robot0_eef_pos": 3, "robot0_eef_quat": 4, "robot0_gripper_qpos": 2}
# Per-step bounds (tests/dataset/test_robosuite_equivalence.py): our controllers are
# robosuite's, linearized once per 50 ms step.
PER_STEP_MEDIAN_M = 0.001
PER_STEP_MAX_M = 0.003


@dataclass(frozen=True)
class CheckResult:
    name: str
    verdict: Verdict
    detail: str


def check_dataset(
    path: Path, demos: int = 3, progress: Callable[[int, int], None] | None = None
) -> list[CheckResult]:
    """Run every check on the first ``demos`` demos (the obs check reads all)."""
    with open_dataset(path) as file:
        names = sorted(file["data"], key=lambda n: int(n.split("_")[-1]))[: max(1, demos)]
    checks: list[Callable[[Path, list[str]], CheckResult]] = [
        _env_info_and_states,
        _actions,
        _absolute_actions,
        _scene_from_env_args,
        _observations,
    ]
    results = []
    for i, check in enumerate(checks):
        try:
            results.append(check(path, names))
        except Exception as error:  # a check that cannot run is a failed check, said why
            results.append(CheckResult(check.__name__.strip("_"), "fail", f"{error}"))
        if progress is not None:
            progress(i + 1, len(checks))
    return results


def _env_info_and_states(path: Path, names: list[str]) -> CheckResult:
    from crowdteleop.dataset.robosuite_replay import play_states_in_robosuite

    worst = 0.0
    for name in names:
        playback = play_states_in_robosuite(str(path), name)
        worst = max(worst, playback.max_state_error)
    verdict: Verdict = "pass" if worst == 0.0 else "fail"
    return CheckResult(
        "env_info + states",
        verdict,
        f"robosuite.make(**env_info) rebuilt {len(names)} demos; states read back with max "
        f"error {worst:.3g}",
    )


def _env_args(path: Path) -> tuple[EnvArgs, CompositeController]:
    """The dataset's ``env_args`` and the controller they name."""
    with open_dataset(path) as file:
        env_args = EnvArgs.model_validate_json(file["data"].attrs["env_args"])
    if env_args.controller is None:
        raise ValueError("env_args names no controller_configs: robosuite would use its default")
    return env_args, env_args.controller


def _actions(path: Path, names: list[str]) -> CheckResult:
    from crowdteleop.dataset.replay import ReplayChecker, load_demo

    env_args, controller = _env_args(path)
    medians, maxima, after20, after40 = [], [], [], []
    with ReplayChecker() as checker:
        for name in names:
            drift = checker.robosuite_drift(load_demo(path, name), env_args)
            medians.append(drift.per_step_median_m)
            maxima.append(drift.per_step_max_m)
            after20.append(drift.open_loop_at_m.get(20, np.nan))
            after40.append(drift.open_loop_at_m.get(40, np.nan))
    ok = max(medians) < PER_STEP_MEDIAN_M and max(maxima) < PER_STEP_MAX_M
    arm = controller.arm.type
    return CheckResult(
        "actions (plain robosuite)",
        "pass" if ok else "fail",
        f"{arm}: per step median {max(medians) * 1e3:.2f} mm, max {max(maxima) * 1e3:.2f} mm "
        f"(bounds {PER_STEP_MEDIAN_M * 1e3:.0f} / {PER_STEP_MAX_M * 1e3:.0f} mm); open loop "
        f"after 20 steps {np.nanmedian(after20) * 1e3:.1f} mm, after 40 "
        f"{np.nanmedian(after40) * 1e3:.1f} mm (median)",
    )


def _absolute_actions(path: Path, names: list[str]) -> CheckResult:
    from crowdteleop.dataset.robosuite_replay import RobosuiteReplayer

    env_args, _ = _env_args(path)
    with open_dataset(path) as file:
        configs = file["data"].attrs.get("actions_abs_controller_configs")
        if configs is None or "actions_abs" not in file["data"][names[0]]:
            return CheckResult("actions_abs", "skip", "no actions_abs in this dataset")
        absolute_env = env_args.with_controller(CompositeController.model_validate_json(configs))
        errors20, errors40 = [], []
        for name in names:
            group = file["data"][name]
            states, absolute = group["states"][()], group["actions_abs"][()]
            start = float(group["controller_states"][0][0]) if "controller_states" in group else 0
            model_file = str(group.attrs["model_file"])
            replayer = RobosuiteReplayer(absolute_env, model_file)
            try:
                hands = replayer.open_loop(states[0], absolute, None, start).hands
            finally:
                replayer.close()
            recorded = group["obs/robot0_eef_pos"][()] if "obs" in group else None
            if recorded is None:
                return CheckResult("actions_abs", "skip", "no obs/robot0_eef_pos to compare with")
            error = np.linalg.norm(hands[:-1] - recorded[1:], axis=1)
            errors20.append(error[min(19, len(error) - 1)])
            errors40.append(error[min(39, len(error) - 1)])
    return CheckResult(
        "actions_abs (robosuite absolute OSC)",
        "pass",
        f"open loop after 20 steps {np.median(errors20) * 1e3:.1f} mm, after 40 "
        f"{np.median(errors40) * 1e3:.1f} mm (median): absolute targets do not compound",
    )


def _scene_from_env_args(path: Path, names: list[str]) -> CheckResult:
    """Contacts the demos' model excludes and robosuite's own keeps, if they touch at the
    demos' states (a harmless exclude, e.g. Panda's base, passes)."""
    import xml.etree.ElementTree as ET

    import robosuite

    from crowdteleop.dataset.robosuite_replay import REPLAY_KWARGS, register_task_env

    env_args, _ = _env_args(path)
    with open_dataset(path) as file:
        recorded = str(file["data"][names[0]].attrs["model_file"])
        states = file["data"][names[0]]["states"][()][::10]
        register_task_env(str(file["data"][names[0]].attrs.get("task", "")))

    def excludes(xml: str) -> set[tuple[str, str]]:
        found = ET.fromstring(xml).findall("./contact/exclude")
        return {(str(e.get("body1")), str(e.get("body2"))) for e in found}

    plain = robosuite.make(env_args.env_name, **env_args.robosuite_kwargs(**REPLAY_KWARGS))
    try:
        missing = excludes(recorded) - excludes(plain.sim.model.get_xml())
        touching = _touching_share(plain.sim, missing, states)
    finally:
        plain.close()
    if not touching:
        return CheckResult(
            "scene from env_args",
            "pass",
            "robosuite.make(**env_args) builds the demos' contacts"
            + (f" ({len(missing)} excluded pair(s) never touch)" if missing else ""),
        )
    pairs = ", ".join(f"{a}/{b} ({share:.0%} of states)" for (a, b), share in touching.items())
    return CheckResult(
        "scene from env_args",
        "fail",
        f"robosuite's own model keeps contacts the demos' model excludes, touching at the "
        f"demos' states: {pairs}. A policy rolled out from env_args alone meets them (on "
        "Sawyer joint 0 sticks and the hand cannot reach); roll out after "
        "reset_from_xml_string(model_file), or record on Panda or with "
        "exclude_base_contacts=False (docs/dataset.md)",
    )


def _touching_share(
    sim: Any, pairs: set[tuple[str, str]], states: Any
) -> dict[tuple[str, str], float]:
    """Of each body pair, the share of ``states`` at which robosuite's model has it touch."""
    model, data = sim.model, sim.data
    ids = {pair: {model.body_name2id(pair[0]), model.body_name2id(pair[1])} for pair in pairs}
    counts = dict.fromkeys(pairs, 0)
    for state in states:
        sim.set_state_from_flattened(state)
        sim.forward()
        touching = {
            frozenset((model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]))
            for c in data.contact[: data.ncon]
        }
        for pair, bodies in ids.items():
            counts[pair] += frozenset(bodies) in touching
    return {pair: n / len(states) for pair, n in sorted(counts.items()) if n}


def _observations(path: Path, names: list[str]) -> CheckResult:
    with h5py.File(path, "r") as file:
        for name in file["data"]:
            group = file["data"][name]
            for folder in ("obs", "next_obs"):
                missing = [k for k in STOCK_LOW_DIM if f"{folder}/{k}" not in group]
                if missing:
                    return CheckResult(
                        "obs (robomimic stock keys)",
                        "fail",
                        f"{name}/{folder} lacks {', '.join(missing)}: rebuild with --obs low-dim",
                    )
                for key, width in STOCK_SHAPES.items():
                    shape = group[f"{folder}/{key}"].shape
                    if shape != (group.attrs["num_samples"], width):
                        return CheckResult(
                            "obs (robomimic stock keys)", "fail", f"{name}/{folder}/{key}: {shape}"
                        )
    loaded = _sequence_dataset_length(path)
    return CheckResult(
        "obs (robomimic stock keys)",
        "pass",
        f"{', '.join(STOCK_LOW_DIM)} in obs/ and next_obs/ of every demo; "
        + (f"robomimic's SequenceDataset loads {loaded} samples" if loaded else "robomimic absent"),
    )


def _sequence_dataset_length(path: Path) -> int | None:
    try:
        import robomimic.utils.obs_utils as obs_utils
        from robomimic.utils.dataset import SequenceDataset
    except ImportError:
        return None
    obs_utils.initialize_obs_utils_with_obs_specs(
        {"obs": {"low_dim": list(STOCK_LOW_DIM), "rgb": []}}
    )
    dataset = SequenceDataset(
        hdf5_path=str(path),
        obs_keys=STOCK_LOW_DIM,
        dataset_keys=("actions", "rewards", "dones"),
        load_next_obs=True,
        frame_stack=1,
        seq_length=10,
        pad_frame_stack=True,
        pad_seq_length=True,
        get_pad_mask=False,
        goal_mode=None,
        hdf5_cache_mode=None,
        hdf5_use_swmr=True,
        hdf5_normalize_obs=False,
        filter_by_attribute=None,
    )
    return len(dataset)
