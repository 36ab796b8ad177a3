"""Bounds on the numbers a user gives, in a leaf module: the commands check them before they
import the libraries (PyTorch, Stable-Baselines3) that impose them."""

from __future__ import annotations

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
