"""Bounds on the numbers a user gives, in a leaf module: the commands check them before they
import the libraries (PyTorch, Stable-Baselines3) that impose them."""

from __future__ import annotations

SEED_MAX = 2**32 - 1
"""The largest seed a run takes: NumPy's legacy seeding, which Stable-Baselines3 uses, stops
there."""
