#!/usr/bin/env bash
# The guide's task (pick, place and screw down the M12 nut): the expert reward on the ITN that
# `itskill learn` trains, as in ../itn_300k_lownoise/command.sh, but with PPO's learning rate
# 1e-5 instead of the packaged 3e-5 (hyperparams.toml here: the packaged file with that one
# change, hyperparams.diff). 2026-12-05, the project machine (2 vCPUs), two runs at a time.
set -euo pipefail
out=results/learn_pickplacescrew_m12/itn_300k_lr1e5
for seed in 0 1; do
  itskill transfer train pickplacescrew_nut_m12 --method itn --sources auto --reward expert \
    --algo ppo --steps 300000 --seed $seed --eval-every 20000 --eval-episodes 50 --num-envs 16 \
    --k 3 --hyperparams $out/hyperparams.toml --out runs/pps_itn_lr1e5/expert_seed$seed
  itskill eval pickplacescrew_nut_m12 --policy runs/pps_itn_lr1e5/expert_seed$seed/best \
    --episodes 100 --seed 10000 --num-envs 25 --json > "$out/expert_seed${seed}_heldout.json"
done
# Seed 2, 2026-12-05 (fifth session), with 1e-5 packaged since (so no --hyperparams), beside a
# clean-clone test run:
itskill transfer train pickplacescrew_nut_m12 --method itn --sources auto --reward expert \
  --algo ppo --steps 300000 --seed 2 --eval-every 20000 --eval-episodes 50 --num-envs 16 \
  --k 3 --out runs/pps_itn_lr1e5/expert_seed2
itskill eval pickplacescrew_nut_m12 --policy runs/pps_itn_lr1e5/expert_seed2/best \
  --episodes 100 --seed 10000 --num-envs 25 --json > "$out/expert_seed2_heldout.json"
# seeds34/: seeds 3 and 4 of both rewards, 2026-12-05 (evening), the packaged settings (1e-5),
# the generated reward of the learn run of seed 0, two runs at a time beside test runs:
python benchmarks/reward_at_budget.py --task pickplacescrew_nut_m12 \
  --reward results/learn_pickplacescrew_m12/lr1e5_learn/seed0/reward/best_reward.py \
  --seeds 3 4 --workers 2 --out runs/pps_rab --results results/learn_pickplacescrew_m12/itn_300k_lr1e5/seeds34
