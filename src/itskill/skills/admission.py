"""What a skill must be before the skill space takes it, from `skills add` or a library's manifest.

A skill is a source a transfer will load and trust: its checkpoint must load as a policy (a
truncated or foreign file fails here, not at the skill's first use), it must have been trained on
the skill's task where the checkpoint records one, and it must name at least one action, which
retrieval and the analyzer read.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from itskill.skills.store import SkillSpaceError


class InadmissibleSkillError(SkillSpaceError):
    """A skill whose checkpoint, task or actions the skill space cannot use."""


def check_admissible(task_id: str, checkpoint: Path, actions: Sequence[str]) -> None:
    """Raise :class:`InadmissibleSkillError` (or ``UnknownTaskError``) unless a skill of task
    ``task_id`` with ``actions`` and the policy in ``checkpoint`` (``policy.safetensors`` of a
    checkpoint directory, or a Stable-Baselines3 ``.zip``) can serve as a transfer source.

    A missing checkpoint passes: the skill space names it when the skill is added.
    """
    from itskill.rl.checkpoint import (
        POLICY_FILE,
        CheckpointError,
        as_policy,
        policy_location,
        read_meta,
    )
    from itskill.tasks import get_task
    from itskill.tasks.evaluate import make_policy

    spec = get_task(task_id)
    if not any(a.strip() for a in actions):
        raise InadmissibleSkillError(
            f"a skill of {spec.id} needs at least one action (its task's are: "
            f"{', '.join(spec.actions)})"
        )
    if not Path(checkpoint).exists():
        return
    if Path(checkpoint).suffix == ".safetensors" and Path(checkpoint).name != POLICY_FILE:
        # Every reader loads the policy.safetensors beside it: the skill would record one
        # file and run another.
        raise InadmissibleSkillError(
            f"{checkpoint}: a policy is read from its run's or skill's {POLICY_FILE}; give that "
            "file or its directory"
        )
    location = policy_location(checkpoint)
    try:
        make_policy(as_policy(location), spec, num_envs=1)
        # A checkpoint directory records the task its policy learned, so a skill cannot claim
        # another; a Stable-Baselines3 .zip records none and is taken at its word.
        trained_on = read_meta(location)["task"] if location.is_dir() else spec.id
    except CheckpointError as err:
        raise InadmissibleSkillError(str(err)) from err
    if trained_on != spec.id:
        raise InadmissibleSkillError(
            f"{checkpoint}: the policy was trained on task {trained_on!r}, not {spec.id!r}"
        )
