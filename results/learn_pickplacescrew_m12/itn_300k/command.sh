#!/usr/bin/env bash
# Rewards compared on the network `itskill learn` trains for the guide's command: ITN over the
# `auto` sources, PPO, 300k env-steps, 16 environments, 50 evaluation episodes every 20k (the
# learn run's transfer settings), then each run's best/ policy on the learn run's 100 held-out
# episodes (seed 10,000, 25 environments). Seed 0 of the generated reward is the learn run itself
# (../transfer/, ../evaluation.json); seed 1 trains the reward it chose (../reward/best_reward.py)
# the same way. expert_lr3e5_seed0_stopped180k_eval.csv: the expert reward with PPO's learning
# rate at 3e-5 (a copy of the packaged hyper-parameters with
# [nutbolt.tasks.pickplacescrew_nut_m12.ppo] learning_rate = 3e-5), stopped by hand at 180k.
set -euo pipefail
out=results/learn_pickplacescrew_m12/itn_300k
train() {  # reward name, reward (expert or a file), seed
  itskill transfer train pickplacescrew_nut_m12 --method itn --sources auto --reward "$2" \
    --algo ppo --steps 300000 --seed "$3" --eval-every 20000 --eval-episodes 50 --num-envs 16 \
    --k 3 --out "runs/pps_itn/$1_seed$3"
  itskill eval pickplacescrew_nut_m12 --policy "runs/pps_itn/$1_seed$3/best" --episodes 100 \
    --seed 10000 --num-envs 25 --json > "$out/$1_seed$3_heldout.json"
}
train expert expert 0
train expert expert 1
train generated results/learn_pickplacescrew_m12/reward/best_reward.py 1
