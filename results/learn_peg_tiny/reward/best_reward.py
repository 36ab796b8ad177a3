# Staged reward for: Pick up the rectangular peg and insert it into the rectangular hole
# Written by itskill's offline rule-based backend (not a language model), sample 1.
import numpy as np


def compute_reward(ctx):
    """Staged shaping per subtask + stage bonus + success bonus - action penalty."""
    stage = np.asarray(ctx["stage"]).astype(np.int64)
    # Temperatures (metres or radians): one per transformed term.
    temp_reach_0 = 0.04408  # grip point to the part's centre
    temp_centre_1 = 0.0062838  # grip point to the part's grip zone (lateral offset and the vertical offset beyond half the part height)
    temp_lift_2 = 0.021307  # height still to gain until the part bottom is at 0.3 * ctx["obj_height"][:, 0], while held
    temp_to_fixture_3 = 0.033664  # part bottom to a point 0.015 m over its fixture point
    temp_engage_4 = 0.0070406  # part bottom to the fixture point, 1 once engaged
    temp_yaw_4 = 0.29876  # part yaw to fixture yaw
    temp_hole_centre_5 = 0.0072409  # lateral offset of the part bottom from the hole's axis
    temp_yaw_5 = 0.13407  # part yaw to fixture yaw
    temp_depth_5 = 0.017013  # insertion depth still missing to 0.5 of the hole depth, while in the hole
    # Term weights: a completed stage keeps paying its terms' full weight.
    w_reach_0 = 1.245
    w_centre_1 = 0.6439
    w_grasped_1 = 0.8858
    w_lift_2 = 1.378
    w_to_fixture_3 = 0.7133
    w_hold_3 = 0.2151
    w_engage_4 = 1.4
    w_yaw_4 = 0.408
    w_hole_centre_5 = 0.6177
    w_yaw_5 = 0.3743
    w_depth_5 = 0.899
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
    # stage 2: lift (object 0, recipe lift)
    d = np.maximum(0.3 * ctx["obj_height"][:, 0] - ctx["obj_bottom_z"][:, 0], 0.0)
    value = 1.0 - np.tanh(d / temp_lift_2)
    value = value * ctx["grasped"][:, 0]
    components["2.lift/lift"] = w_lift_2 * np.where(stage > 2, 1.0, np.where(stage == 2, value, 0.0))
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
    d = np.abs(ctx["yaw_error"][:, 0])
    value = 1.0 - np.tanh(d / temp_yaw_4)
    components["4.place/yaw"] = w_yaw_4 * np.where(stage > 4, 1.0, np.where(stage == 4, value, 0.0))
    # stage 5: insert (object 0, recipe insert)
    d = np.linalg.norm(ctx["obj_to_fix"][:, 0, :2], axis=-1)
    value = 1.0 - np.tanh(d / temp_hole_centre_5)
    components["5.insert/hole_centre"] = w_hole_centre_5 * np.where(stage > 5, 1.0, np.where(stage == 5, value, 0.0))
    d = np.abs(ctx["yaw_error"][:, 0])
    value = 1.0 - np.tanh(d / temp_yaw_5)
    components["5.insert/yaw"] = w_yaw_5 * np.where(stage > 5, 1.0, np.where(stage == 5, value, 0.0))
    d = np.maximum(0.5 * (ctx["fix_pos"][:, 0, 2] - ctx["seat_z"][:, 0]) - ctx["insertion_depth"][:, 0], 0.0)
    value = 1.0 - np.tanh(d / temp_depth_5)
    value = value * ctx["engaged"][:, 0]
    components["5.insert/depth"] = w_depth_5 * np.where(stage > 5, 1.0, np.where(stage == 5, value, 0.0))
    success = ((ctx["engaged"][:, 0] > 0.5) & (ctx["insertion_depth"][:, 0] >= 0.5 * (ctx["fix_pos"][:, 0, 2] - ctx["seat_z"][:, 0])) & (np.abs(ctx["yaw_error"][:, 0]) <= 0.1) & (ctx["obj_tilt"][:, 0] <= 0.1))
    components["stage_bonus"] = stage_bonus * stage.astype(np.float64)
    components["success"] = success_bonus * success.astype(np.float64)
    motion = np.asarray(ctx["action"], dtype=np.float64)[:, :4]
    components["action_penalty"] = -action_penalty * np.mean(motion**2, axis=-1)
    total = sum(components.values())
    return total, components
