#!/usr/bin/env bash
# The shipped (one-scale) synthesiser's chosen pick-and-place reward against the expert reward on
# the ITN for 300k env-steps, seeds 1-4, best/ on 100 held-out episodes. Seeds 1-3 are the runs of
# ../at_300k (already at 300k, re-evaluated here: 25 environments draw other held-out episodes than
# `itskill eval`'s 16); seed 4 was trained by this command. ITSKILL_HOME held the shipped library.
set -euo pipefail
python benchmarks/reward_at_budget.py --reward results/reward_search/pickplace_nut_m12_itn/best_reward.py \
  --seeds 1 2 3 4 --workers 2 --out runs/pp300k --results results/reward_search/pickplace_nut_m12_itn/at_300k_4seeds
