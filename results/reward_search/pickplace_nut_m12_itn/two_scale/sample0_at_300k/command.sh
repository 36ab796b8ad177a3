#!/usr/bin/env bash
# Sample 0 of the two-scale synthesiser (commit 3e2a319, since reverted: the recipe's default
# temperatures and weights, no variation; the search's iter_0/sample_0/reward.py) against the
# expert reward on the ITN for 300k env-steps, seeds 1-3: is the recipe or the search's
# variation of it behind ../at_300k's figures? Expert runs copied as in ../at_300k/command.sh.
set -euo pipefail
mkdir -p runs/pp300k_s0 && cp -r runs/pp300k/expert_seed{1,2,3} runs/pp300k_s0/
python benchmarks/reward_at_budget.py \
  --reward results/reward_search/pickplace_nut_m12_itn/two_scale/sample0_at_300k/reward.py \
  --workers 3 --out runs/pp300k_s0 --results results/reward_search/pickplace_nut_m12_itn/two_scale/sample0_at_300k
