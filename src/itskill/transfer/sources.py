"""Source skills for a transfer: chosen from the skill space, loaded as frozen policies.

``resolve_sources(target, "auto")`` retrieves skills by the similarity of their text to the target
task's command (:func:`itskill.skills.retrieval.search`, the paper's SBERT retrieval). With
``distinct_actions`` (the default) one skill of each action sequence is kept, the first the
ranking below picks, so the ``k`` sources are ``k`` different behaviours rather than one primitive
on several part sizes. The skills are taken to cover the target's steps (see
:func:`resolve_sources`: family, success, steps covered, parts and start come before similarity),
as similarity alone ranks a screw first for a pick-and-place.

Every source must be a finished checkpoint on the shared observation layout and action space:
:func:`itskill.rl.checkpoint.read_meta` checks the layout, and a missing skill or checkpoint is a
:class:`SourceError` naming it. ``"auto"`` passes over skills whose checkpoint is a
Stable-Baselines3 ``.zip`` (``itskill skills add`` takes one for evaluation), which no transfer can
load as a source; named, such a skill is an error.
"""

from __future__ import annotations

import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.policies import ActorCriticPolicy

from itskill.rl.checkpoint import (
    META_FILE,
    STAGED_POLICY_CLASS,
    load_policy,
    policy_location,
    policy_sha256,
    read_meta,
)
from itskill.sim.vec_env import action_space
from itskill.skills import SkillSpace, SkillSpaceError, open_skill_space, search
from itskill.skills.store import Skill, is_serial_number
from itskill.tasks import UnknownTaskError, get_task
from itskill.tasks.evaluate import CheckpointError
from itskill.tasks.spec import TaskSpec
from itskill.transfer.config import TransferConfig, load_transfer_config
from itskill.transfer.stages import runs

AUTO = "auto"


class SourceError(ValueError):
    """A source skill that cannot be used (unknown, no checkpoint, wrong layout), or sources a
    method cannot choose among; ``setting`` is then the :class:`TransferConfig` field that rules
    them out (``pst_keep``), for a caller to name where the user set it."""

    def __init__(self, message: str, setting: str | None = None) -> None:
        super().__init__(message)
        self.setting = setting


class IncompatibleSourceError(ValueError):
    """A source network the target cannot join: its stages differ from the target's."""


@dataclass(frozen=True)
class SourceSkill:
    """A skill chosen as a transfer source, with the checkpoint directory its policy is read from.

    ``score`` is the retrieval similarity (None when the skill was named explicitly).
    """

    id: int | None
    name: str
    task_id: str
    description: str
    actions: tuple[str, ...]
    run_dir: Path
    success_rate: float | None
    score: float | None
    policy_class: str
    policy: dict[str, Any]
    weights_sha256: str
    """Of the weights the analyzer and the network take: a skill retrained later is told apart."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "name": self.name,
            "task": self.task_id,
            "description": self.description,
            "actions": list(self.actions),
            "run_dir": str(self.run_dir),
            "success_rate": self.success_rate,
            "score": self.score,
            "weights_sha256": self.weights_sha256,
        }

    def spec(self) -> dict[str, Any]:
        """What a transfer policy needs to rebuild this source (``sources=`` of its kwargs)."""
        return {
            "name": self.name,
            "task": self.task_id,
            "run_dir": str(self.run_dir),
            "policy_class": self.policy_class,
            "policy": self.policy,
            "weights_sha256": self.weights_sha256,
        }

    def analyzer_entry(self) -> dict[str, Any]:
        """The ``{id, description, actions}`` the analyzer prompt takes."""
        return {"id": self.name, "description": self.description, "actions": list(self.actions)}


def is_stages(value: Any) -> bool:
    """Whether ``value`` is a network's stages as a record holds them: a non-empty list of
    layer widths (whole numbers above 0)."""
    return (
        isinstance(value, list)
        and bool(value)
        and all(isinstance(w, int) and not isinstance(w, bool) and w > 0 for w in value)
    )


def _source_of(space: SkillSpace, skill: Skill, score: float | None) -> SourceSkill:
    run_dir = policy_location(space.checkpoint_path(skill))
    try:
        meta = read_meta(run_dir)
    except CheckpointError as err:
        raise SourceError(f"skill {skill.name!r} (id {skill.id}): {err}") from err
    stages = meta["policy"].get("stages")
    if not is_stages(stages):
        # The transfer networks take their lateral connections from these stages.
        raise SourceError(
            f"skill {skill.name!r} (id {skill.id}): {run_dir / META_FILE}: corrupt policy "
            f"description: stages must be a list of layer widths, got {stages!r}"
        )
    n_actions = int(action_space().shape[0])
    if meta.get("action_size", n_actions) != n_actions:
        raise SourceError(
            f"skill {skill.name!r}: its policy has {meta['action_size']} actions, "
            f"the tasks have {n_actions}"
        )
    try:
        digest = policy_sha256(run_dir)
    except OSError as err:
        raise SourceError(f"skill {skill.name!r} (id {skill.id}): its weights: {err}") from err
    return SourceSkill(
        id=skill.id,
        name=skill.name,
        task_id=skill.task_id,
        description=skill.description,
        actions=tuple(skill.actions),
        run_dir=run_dir,
        success_rate=skill.success_rate,
        score=score,
        policy_class=meta.get("policy_class", STAGED_POLICY_CLASS),
        policy=meta["policy"],
        weights_sha256=digest,
    )


class SourceWarning(UserWarning):
    """A skill retrieval passed over: its checkpoint cannot be read as a source."""


_SB3_ZIP = "a Stable-Baselines3 .zip"


def _passed_over(space: SkillSpace, skill: Skill) -> str | None:
    """Why ``skill``'s checkpoint is not of the kind a transfer loads, or None if it is: weights
    whose directory holds readable metadata of this release's observations
    (:func:`policy_location`, :func:`read_meta`). A Stable-Baselines3 ``.zip`` (which ``skills
    add`` takes, for eval) is not; nor is a damaged checkpoint or one of an older observation
    layout, which, ranked first, failed every retrieval it won a place in."""
    path = space.checkpoint_path(skill)
    location = policy_location(path)
    if location == path:
        return _SB3_ZIP
    try:
        read_meta(location)
    except CheckpointError as err:
        return str(err)
    return None


def parse_keys(sources: str | Sequence[int | str]) -> list[int | str]:
    """The skills a source list names, in order: serial numbers as ints, names as strings
    (``"3, pick_nut_m12"`` and ``[3, "pick_nut_m12"]`` alike)."""
    items = sources.split(",") if isinstance(sources, str) else list(sources)
    keys: list[int | str] = []
    for item in items:
        if not isinstance(item, str | numbers.Integral) or isinstance(item, bool | np.bool_):
            # True == 1 would pick skill 1.
            raise SourceError(
                f"a source skill is named by its serial number or name, got "
                f"{type(item).__name__} {item!r} in {sources!r}"
            )
        key = item.strip() if isinstance(item, str) else int(item)  # NumPy's ids as Python's
        if key == "":
            raise SourceError(f"empty skill name in the source list {sources!r}")
        keys.append(int(key) if isinstance(key, str) and is_serial_number(key) else key)
    return keys


def _placement(actions: tuple[str, ...], target: tuple[str, ...], covered: set[int]) -> set[int]:
    """The positions of ``target`` that ``actions`` would newly cover: of the places where it
    occurs as a contiguous run, the one covering most positions not yet in ``covered``."""
    best: set[int] = set()
    for i in runs(target, actions):
        new = set(range(i, i + len(actions))) - covered
        if len(new) > len(best):
            best = new
    return best


def _differences(skill: Skill, target: TaskSpec) -> tuple[bool, bool, bool]:
    """Where ``skill``'s own task differs from ``target``: (another task family, other parts,
    the parts started otherwise). A nut's place was learned on another part than a peg task's;
    a rectangular peg's pick is not the round peg's; a remove starts with the peg in its hole,
    a pick on the table. A skill whose task this installation does not know (added from a
    user's task files that are not loaded now) counts as another family, nothing more."""
    try:
        own = get_task(skill.task_id)
    except UnknownTaskError:
        return True, False, False
    return (
        own.family != target.family,
        [p.name for p in own.objects] != [p.name for p in target.objects],
        [o.mode for o in own.init.objects] != [o.mode for o in target.init.objects],
    )


def resolve_sources(
    target: str,
    sources: str | Sequence[int | str] = AUTO,
    config: TransferConfig | None = None,
    space: SkillSpace | None = None,
    exclude_target: bool = True,
) -> list[SourceSkill]:
    """The source skills for ``target``: retrieved (``"auto"``) or named (ids or names).

    ``"auto"`` takes ``config.k`` skills one at a time: the skill whose action sequence, as a
    contiguous run of the target's, performs the most target steps no skill taken so far
    performs; skills learned in the target's task family before others, then those learned on
    the target's own parts, and for the target's first steps those whose task starts the parts
    as the target's does; ties by similarity to the target's command. It skips the target's own
    task when ``exclude_target``, repeated action sequences when ``config.distinct_actions``, and
    skills whose checkpoint is a Stable-Baselines3 ``.zip`` (no transfer loads one; the error
    when no skill is left names them). A skill whose recorded success is below
    ``config.min_success`` comes after every other skill of its family: one learned on a smoke
    budget would otherwise, performing more of the target's steps, displace the working skills
    it was learned from. ``config`` defaults to the packaged ``transfer.toml``'s. Named skills
    (``"3,5"``, ``"pick_nut_m12,place_nut_m12"`` or a list) are used as given, in that order.
    ``space`` defaults to the user's skill space (:func:`open_skill_space`).
    """
    config = load_transfer_config() if config is None else config
    k, distinct_actions, min_success = config.k, config.distinct_actions, config.min_success
    spec = get_task(target)
    own = space is None
    space = open_skill_space() if space is None else space
    try:
        if isinstance(sources, str) and sources.strip() == AUTO:
            exclude = {spec.id} if exclude_target else set()
            ranked = search(space, spec.command, k=len(space), exclude_tasks=exclude)
            unloadable = {
                skill.name: why for skill, _ in ranked if (why := _passed_over(space, skill))
            }
            for name, why in unloadable.items():
                if why != _SB3_ZIP:  # the user's to mend, where they would look
                    warnings.warn(f"skill {name!r} passed over: {why}", SourceWarning, stacklevel=2)
            ranked = [(skill, score) for skill, score in ranked if skill.name not in unloadable]
            target_steps = tuple(spec.actions)
            chosen: list[tuple[Skill, float | None]] = []
            seen: set[tuple[str, ...]] = set()
            covered: set[int] = set()
            pool = [
                (
                    skill,
                    score,
                    _differences(skill, spec),
                    bool(runs(target_steps, skill.actions)),
                    skill.success_rate is not None and skill.success_rate < min_success,
                )
                for skill, score in ranked
            ]
            while pool and len(chosen) < k:
                # Greedy cover of the target's steps: next, the skill that performs the most
                # steps no chosen skill performs yet (a pick covers approach, grasp and lift of
                # a pick-and-place, so a lift adds nothing after it, a place two steps). Skills
                # of the target's own family first: a nut's "approach, place" fits steps of a
                # peg task but was learned on another part; of those, skills that work (a
                # policy below min_success performs its steps in name only). Then skills of the
                # target's own
                # parts, and for the first steps those that start where the target starts.
                # Once every step is covered, a skill that performs some of them comes before
                # one that performs none (a screw is no source for a pick-and-place, however
                # alike the commands read). Ties keep the similarity order.
                adds = [_placement(sk.actions, target_steps, covered) for sk, *_ in pool]
                best = min(
                    range(len(pool)),
                    key=lambda j: (
                        pool[j][2][0],
                        pool[j][4],
                        -len(adds[j]),
                        not pool[j][3],
                        pool[j][2][1],
                        0 in adds[j] and pool[j][2][2],
                    ),
                )
                skill, score, *_ = pool.pop(best)
                if distinct_actions and tuple(skill.actions) in seen:
                    continue
                seen.add(tuple(skill.actions))
                covered |= adds[best]
                chosen.append((skill, score))
            if not chosen:
                passed_over = (
                    " (passed over, as a Stable-Baselines3 .zip or a checkpoint this release "
                    f"cannot read as a source: {', '.join(unloadable)})"
                    if unloadable
                    else ""
                )
                raise SourceError(
                    f"the skill space ({space.path}) has no skill to transfer to {target!r} "
                    f"from{passed_over}; train or install some (`itskill skills pretrain`, "
                    "`itskill skills install`)"
                )
        else:
            keys = parse_keys(sources)
            if not keys:
                raise SourceError("no source skills given (expected 'auto' or ids/names)")
            try:
                chosen = [(space.get(key), None) for key in keys]
            except SkillSpaceError as err:
                raise SourceError(str(err)) from err
            names = [s.name for s, _ in chosen]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise SourceError(f"source skill(s) given more than once: {', '.join(dup)}")
        return [_source_of(space, skill, score) for skill, score in chosen]
    finally:
        if own:
            space.close()


def freeze(policy: ActorCriticPolicy) -> ActorCriticPolicy:
    """``policy`` with every parameter frozen, in eval mode, normaliser statistics fixed."""
    for p in policy.parameters():
        p.requires_grad_(False)
    policy.update_obs_stats = False
    policy.set_training_mode(False)
    return policy


def load_source(spec: dict[str, Any]) -> ActorCriticPolicy:
    """The frozen policy of a source ``spec`` (:meth:`SourceSkill.spec`), read from its run dir."""
    try:
        return freeze(load_policy(spec["run_dir"]))
    except CheckpointError as err:
        raise SourceError(f"source {spec.get('name')!r}: {err}") from err
