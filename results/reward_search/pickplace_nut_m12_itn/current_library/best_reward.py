# Staged reward for: Pick up the nut and place it on the bolt
# Written by itskill's offline rule-based backend (not a language model), sample 2.
import numpy as np


def compute_reward(ctx):
    """Staged shaping per subtask + stage bonus + success bonus - action penalty."""
    stage = np.asarray(ctx["stage"]).astype(np.int64)
    # Temperatures (metres or radians): one per transformed term.
    temp_reach_0 = 0.12497  # grip point to the part's centre
    temp_centre_1 = 0.010855  # grip point to the part's grip zone (lateral offset and the vertical offset beyond half the part height)
    temp_upright_1 = 0.24717  # part tilt beyond half the 20.0 degrees allowed
    temp_lift_2 = 0.021229  # height still to gain until the part bottom is at 1.0 * ctx["obj_height"][:, 0], while held
    temp_upright_2 = 0.15906  # part tilt beyond half the 20.0 degrees allowed
    temp_to_fixture_3 = 0.078301  # part bottom to a point 0.015 m over its fixture point
    temp_engage_4 = 0.010473  # part bottom to the fixture point, 1 once engaged
    # Term weights: a completed stage keeps paying its terms' full weight.
    w_reach_0 = 0.927
    w_centre_1 = 0.6713
    w_grasped_1 = 1.006
    w_upright_1 = 0.5342
    w_lift_2 = 1.16
    w_upright_2 = 0.5025
    w_to_fixture_3 = 0.7209
    w_hold_3 = 0.2734
    w_engage_4 = 0.7974
    stage_bonus = 1
    success_bonus = 2
    action_penalty = 0.01

    components = {}
    # stage 0: approach (object 0, recipe approach)
    d = np.linalg.norm(ctx["obj_to_ee"][:, 0], axis=-1)
    value = 1.0 - np.tanh(d / temp_reach_0)
    components["0.approach/reach"] = w_reach_0 * np.where(stage > 0, 1.0, np.where(stage == 0, value, 0.0))
    # stage 1: grasp (object 0, recipe grasp)
    d = np.hypot(np.linalg.norm(ctx["obj_to_ee"][:, 0, :2], axis=-1), np.maximum(np.abs(ctx["obj_to_ee"][:, 0, 2]) - 0.5 * ctx["obj_height"][:, 0], 0.0))
    value = 1.0 - np.tanh(d / temp_centre_1)
    components["1.grasp/centre"] = w_centre_1 * np.where(stage > 1, 1.0, np.where(stage == 1, value, 0.0))
    value = ctx["grasped"][:, 0]
    components["1.grasp/grasped"] = w_grasped_1 * np.where(stage > 1, 1.0, np.where(stage == 1, value, 0.0))
    d = np.maximum(ctx["obj_tilt"][:, 0] - 0.5 * np.radians(20.0), 0.0)
    value = 1.0 - np.tanh(d / temp_upright_1)
    components["1.grasp/upright"] = w_upright_1 * np.where(stage > 1, 1.0, np.where(stage == 1, value, 0.0))
    # stage 2: lift (object 0, recipe lift)
    d = np.maximum(1.0 * ctx["obj_height"][:, 0] - ctx["obj_bottom_z"][:, 0], 0.0)
    value = 1.0 - np.tanh(d / temp_lift_2)
    value = value * ctx["grasped"][:, 0]
    components["2.lift/lift"] = w_lift_2 * np.where(stage > 2, 1.0, np.where(stage == 2, value, 0.0))
    d = np.maximum(ctx["obj_tilt"][:, 0] - 0.5 * np.radians(20.0), 0.0)
    value = 1.0 - np.tanh(d / temp_upright_2)
    components["2.lift/upright"] = w_upright_2 * np.where(stage > 2, 1.0, np.where(stage == 2, value, 0.0))
    # stage 3: approach (object 0, recipe carry)
    d = np.linalg.norm(ctx["obj_to_fix"][:, 0] + np.array([0.0, 0.0, 0.015]), axis=-1)
    value = 1.0 - np.tanh(d / temp_to_fixture_3)
    components["3.approach/to_fixture"] = w_to_fixture_3 * np.where(stage > 3, 1.0, np.where(stage == 3, value, 0.0))
    value = ctx["grasped"][:, 0]
    components["3.approach/hold"] = w_hold_3 * np.where(stage > 3, 1.0, np.where(stage == 3, value, 0.0))
    # stage 4: place (object 0, recipe place)
    d = np.linalg.norm(ctx["obj_to_fix"][:, 0], axis=-1)
    value = 1.0 - np.tanh(d / temp_engage_4)
    value = np.maximum(ctx["engaged"][:, 0], 0.9 * value)
    components["4.place/engage"] = w_engage_4 * np.where(stage > 4, 1.0, np.where(stage == 4, value, 0.0))
    success = (ctx["engaged"][:, 0] > 0.5)
    components["stage_bonus"] = stage_bonus * stage.astype(np.float64)
    components["success"] = success_bonus * success.astype(np.float64)
    motion = np.asarray(ctx["action"], dtype=np.float64)[:, :4]
    components["action_penalty"] = -action_penalty * np.mean(motion**2, axis=-1)
    total = sum(components.values())
    return total, components
