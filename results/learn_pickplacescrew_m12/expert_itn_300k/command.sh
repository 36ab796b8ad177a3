#!/usr/bin/env bash
# The expert reward on the network `itskill learn` trains for the same command (ITN over the
# `auto` sources, PPO, 300k env-steps, 16 environments, 50 evaluation episodes every 20k, seed 0:
# the learn run's transfer settings, with the expert reward instead of the generated one), then
# its best/ policy on the learn run's 100 held-out episodes (seed 10,000, 25 environments).
# expert_lr3e5_seed0_stopped180k_eval.csv: the same with PPO's learning rate at 3e-5 (a copy of
# the packaged hyper-parameters with [nutbolt.tasks.pickplacescrew_nut_m12.ppo] learning_rate =
# 3e-5), stopped by hand at 180k env-steps.
set -euo pipefail
itskill transfer train pickplacescrew_nut_m12 --method itn --sources auto --reward expert --algo ppo \
  --steps 300000 --seed 0 --eval-every 20000 --eval-episodes 50 --num-envs 16 --k 3 \
  --out runs/pps_expert/seed0
itskill eval pickplacescrew_nut_m12 --policy runs/pps_expert/seed0/best --episodes 100 --seed 10000 \
  --num-envs 25 --json > results/learn_pickplacescrew_m12/expert_itn_300k/seed0_heldout.json
