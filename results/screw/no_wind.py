"""The expert reward of screw_nut_m12 without its wind term (an ablation)."""
from itskill.tasks import get_task
from itskill.tasks.rewards import expert_reward

_expert = expert_reward(get_task("screw_nut_m12"))


def compute_reward(ctx):
    total, components = _expert(ctx)
    wind = components.pop("0.screw/wind")
    return total - wind, components
