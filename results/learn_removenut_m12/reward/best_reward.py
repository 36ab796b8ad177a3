# Staged reward for: Unscrew the M12 nut and lift it off the bolt
# Written by itskill's offline rule-based backend (not a language model), sample 1 (retuned).
import numpy as np


def compute_reward(ctx):
    """Staged shaping per subtask + stage bonus + success bonus - action penalty."""
    stage = np.asarray(ctx["stage"]).astype(np.int64)
    # Temperatures (metres or radians): one per transformed term.
    temp_rise_0 = 0.0060497  # height still to gain until the part bottom is 0.002 m above the fixture point
    temp_stay_on_part_0 = 0.010684  # grip point stays on the part (only a gripped part can be turned)
    temp_rise_1 = 0.0067368  # height still to gain until the part bottom is 0.03 m above the fixture point
    # Term weights: a completed stage keeps paying its terms' full weight.
    w_rise_0 = 0.9864
    w_stay_on_part_0 = 0.6216
    w_rise_1 = 1.171
    w_hold_1 = 0.3772
    stage_bonus = 1
    success_bonus = 2
    action_penalty = 0.01

    components = {}
    # stage 0: unscrew (object 0, recipe unscrew)
    d = np.maximum(ctx["fix_pos"][:, 0, 2] + 0.002 - ctx["obj_bottom_z"][:, 0], 0.0)
    value = np.exp(-d / temp_rise_0)
    components["0.unscrew/rise"] = w_rise_0 * np.where(stage > 0, 1.0, np.where(stage == 0, value, 0.0))
    d = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    value = np.exp(-d / temp_stay_on_part_0)
    components["0.unscrew/stay_on_part"] = w_stay_on_part_0 * np.where(stage > 0, 1.0, np.where(stage == 0, value, 0.0))
    # stage 1: lift (object 0, recipe remove)
    d = np.maximum(ctx["fix_pos"][:, 0, 2] + 0.03 - ctx["obj_bottom_z"][:, 0], 0.0)
    value = np.exp(-d / temp_rise_1)
    components["1.lift/rise"] = w_rise_1 * np.where(stage > 1, 1.0, np.where(stage == 1, value, 0.0))
    value = ctx["grasped"][:, 0]
    components["1.lift/hold"] = w_hold_1 * np.where(stage > 1, 1.0, np.where(stage == 1, value, 0.0))
    success = ((ctx["engaged"][:, 0] <= 0.5) & (ctx["obj_to_fix"][:, 0, 2] <= -0.03)) & (ctx["grasped"][:, 0] > 0.5)
    components["stage_bonus"] = stage_bonus * stage.astype(np.float64)
    components["success"] = success_bonus * success.astype(np.float64)
    motion = np.asarray(ctx["action"], dtype=np.float64)[:, :4]
    components["action_penalty"] = -action_penalty * np.mean(motion**2, axis=-1)
    total = sum(components.values())
    return total, components
