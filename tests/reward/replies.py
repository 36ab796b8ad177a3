"""Scripted reward replies for the loop tests: one good, the others broken in each way a model's
reply can be broken."""

from __future__ import annotations

GOOD = """Here is a staged reward.
```python
import numpy as np


def compute_reward(ctx):
    stage = ctx["stage"]
    d = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    temp_reach = 0.15
    reach = np.where(stage == 0, 1.0 - np.tanh(d / temp_reach), 0.0)
    grasp = np.where(stage == 1, ctx["grasped"][:, 0], 0.0)
    lift = np.where(stage == 2, ctx["obj_bottom_z"][:, 0] / (3 * ctx["obj_height"][:, 0]), 0.0)
    bonus = 1.0 * stage
    components = {"reach": reach, "grasp": grasp, "lift": lift, "stage_bonus": bonus}
    return reach + grasp + lift + bonus, components
```
"""

SYNTAX_ERROR = """```python
def compute_reward(ctx)
    return ctx["time_frac"], {}
```"""

RAISES = """```python
def compute_reward(ctx):
    d = ctx["no_such_key"]
    return d, {"d": d}
```"""

RAISES_LATER = """```python
import numpy as np


def compute_reward(ctx):
    time_left = np.log(0.5 - ctx["time_frac"])
    return time_left, {"time_left": time_left}
```"""
"""Finite on the probe (a few steps into an episode), NaN past half an episode in training."""

ENDLESS = """```python
def compute_reward(ctx):
    x = 0
    while x >= 0:
        x = x + 1
    return ctx["time_frac"], {}
```"""

ESCAPE = """```python
import os


def compute_reward(ctx):
    os.system("echo pwned")
    return ctx["time_frac"], {}
```"""

CONSTANT = """```python
import numpy as np


def compute_reward(ctx):
    zero = np.zeros(ctx["ee_pos"].shape[0])
    return zero, {"zero": zero}
```"""
"""Never converges: nothing to learn from."""

EMPTY = ""
