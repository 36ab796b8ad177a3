#!/usr/bin/env bash
# The guide's task at the pick-and-place settings (2026-12-05): the expert reward on the ITN that
# `itskill learn` trains, as in ../itn_300k/command.sh, with the task trained at log-std -2.0 and
# PPO learning rate 3e-5 (then a copy of the packaged hyper-parameters with
# [nutbolt.tasks.pickplacescrew_nut_m12.policy] log_std_init = -2.0 and
# [nutbolt.tasks.pickplacescrew_nut_m12.ppo] learning_rate = 3e-5; packaged since). Two runs at a
# time on the project machine (2 vCPUs), with an `itskill learn` run and tests beside them.
set -euo pipefail
out=results/learn_pickplacescrew_m12/itn_300k_lownoise
for seed in 0 1; do
  itskill transfer train pickplacescrew_nut_m12 --method itn --sources auto --reward expert \
    --algo ppo --steps 300000 --seed $seed --eval-every 20000 --eval-episodes 50 --num-envs 16 \
    --k 3 --out runs/pps_itn_lownoise/expert_seed$seed
  itskill eval pickplacescrew_nut_m12 --policy runs/pps_itn_lownoise/expert_seed$seed/best \
    --episodes 100 --seed 10000 --num-envs 25 --json > "$out/expert_seed${seed}_heldout.json"
done
