#!/usr/bin/env bash
# The guide's command end to end with PPO at 1e-5 for its task instead of 3e-5 (run from a
# checkout whose src/itskill/rl/data/hyperparams.toml was ../itn_300k_lr1e5/hyperparams.toml;
# packaged since, so a plain `itskill learn` does the same), the default budget, a new skill space
# per seed. 2026-12-05, the project machine (2 vCPUs): seeds 0 and 1 together, then
# seed 2 alone. Only the small files of each run directory are kept here.
set -euo pipefail
for seed in 0 1 2; do
  ITSKILL_HOME=runs/learn_lr1e5_home$seed itskill learn \
    "Pick up the nut, place it on the bolt and screw it down" --seed $seed --out runs/learn_lr1e5/seed$seed
done
