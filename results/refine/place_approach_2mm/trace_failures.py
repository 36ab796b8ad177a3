"""Trace place_nut_m12's failures (docs/skills.md, "Nineteenth pretraining").

    cd results/refine/place_approach_2mm
    python trace_failures.py ../../../src/itskill/skills/library/place_nut_m12

Runs the deterministic policy on 96 episodes (seeds 777-782, 16 environments each), as it is
and with its first six actions halved, and prints each failure's end state and the start's hold
(how far the nut's centre hangs below the grip point).
"""

import argparse

import numpy as np

from itskill.rl import load_policy
from itskill.tasks import get_task, make_batch_env

DEEP_HOLD = 0.010  # m below the grip point


def run(policy, spec, gentle_start: bool, verbose: bool) -> None:
    successes, deep, deep_ok = 0, 0, 0
    for rep in range(6):
        env = make_batch_env(spec, num_envs=16, seed=777 + rep)
        obs = env.reset()
        hold = env.context()["obj_to_ee"][:, 0, 2].copy()
        for t in range(spec.max_steps - 1):
            action, _ = policy.predict(obs, deterministic=True)
            if gentle_start and t < 6:
                action[:, :4] *= 0.5
            obs, *_ = env.step(action)
        ctx = env.context()
        ok = spec.success(ctx)
        successes += ok.sum()
        deep += (hold > DEEP_HOLD).sum()
        deep_ok += ok[hold > DEEP_HOLD].sum()
        for e in np.where(~ok)[0] if verbose else []:
            off = ctx["obj_to_fix"][e, 0]
            print(
                f"seed {777 + rep} env {e:2d}: hold {hold[e] * 1e3:.1f} mm, nut "
                f"{np.linalg.norm(off[:2]) * 1e3:.1f} mm off the axis, tilt "
                f"{np.degrees(ctx['obj_tilt'][e, 0]):.0f} deg, grasped {int(ctx['grasped'][e, 0])}"
            )
        env.close()
    label = "first six actions halved" if gentle_start else "as it is"
    print(f"{label}: {successes} of 96 succeed; {deep_ok} of {deep} holds over 10 mm deep")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a skill or run directory")
    args = parser.parse_args()
    spec = get_task("place_nut_m12")
    policy = load_policy(args.policy)
    run(policy, spec, gentle_start=False, verbose=True)
    run(policy, spec, gentle_start=True, verbose=False)


if __name__ == "__main__":
    main()
