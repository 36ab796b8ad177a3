"""Bounds on the numbers a user gives, in a leaf module: the commands check them before they
import the libraries (PyTorch, Stable-Baselines3) that impose them."""

from __future__ import annotations

from itskill.errors import FieldError

SEED_MAX = 2**32 - 1
"""The largest seed a run takes: NumPy's legacy seeding, which Stable-Baselines3 uses, stops
there."""

EPISODES_MAX = 1_000_000
"""The most episodes one count asks for (an evaluation, a warm start's demonstrations): more than
any success rate needs (±0.1% at 95%), and the bound keeps counts inside NumPy's integers, where a
mistyped 100000000000000 ran a whole training first and then died of MemoryError."""

NUM_ENVS_MAX = 1024
"""The most environments one process steps together. Each holds two MuJoCo ``MjData`` (physics
and the controller's IK) and a row of every rollout buffer, and they are stepped by the process's
own threads: the families train with 16, a thousand is already far past the cores that step them,
and a mistyped 100000000000 crashes every run at allocation instead of failing at load."""

EPISODE_STEPS_MAX = 10_000
"""The longest episode a task may have, in control steps: the packaged tasks run 50 to 260, and
a mistyped 100000000000 ran an evaluation's first episode without end and without a word."""

STEPS_MAX = 1_000_000_000
"""The most env-steps of one training run (a training, a transfer run, an experiment's cell, a
reward candidate): a thousand times the paper's transfer runs (1M). The learning rate decays over
the budget, so a mistyped huge one trains on at an undecayed rate for ever instead of failing at
once; a budget this size takes weeks on any machine we know of."""


def check_steps(steps: int, name: str = "steps") -> None:
    """:class:`~itskill.errors.FieldError` (a ``ValueError``) of field ``name`` unless ``steps``
    (an env-step budget) is from 1 to :data:`STEPS_MAX`."""
    if not 1 <= steps <= STEPS_MAX:
        raise FieldError(name, f"{name} must be between 1 and {STEPS_MAX:,}, got {steps:,}")


DEPTH_MAX = 16
"""The most stages (hidden layers) of a policy network: the paper's has three, and the transfer
network takes a lateral connection and a fusion block per stage of every source."""

WIDTH_MAX = 4096
"""The widest layer of a network a user sizes (the policy's stages, the transfer network's
attention and fusion MLPs): the paper's are 256 units and the packaged ones at most 256, and a
mistyped 2560000 allocates a weight matrix of terabytes when the network is built."""

SOURCES_MAX = 32
"""The most source skills one transfer network takes (``k``, PST's ``keep``): the paper's and the
packaged ``k`` are 3, and every source is a frozen policy run on every step of the training."""

WORKERS_MAX = 1024
"""The most worker processes (or Ray tasks at once) a run asks for: each is a process that trains
one job; a thousand is far past any machine's cores, and a mistyped huge count starts processes
until the machine gives out."""

RETRIES_MAX = 10
"""The most times a model's reply that does not validate is sent back (the analyzer's
``retries``, the reward search's ``max_regenerations``): each is a paid model call, and the
packaged values are 2 and 3."""

SEED_COUNT_MAX = 1000
"""The most seeds given as a count (an experiment's ``seeds = 5``, the reward search's
``select_seeds`` and ``final_seeds``): each is a whole training per task, method or reward, so a
mistyped 50000 for 5 would queue that many."""
