#!/usr/bin/env bash
# The two-scale synthesiser's chosen pick-and-place reward (../best_reward.py, from commit 3e2a319,
# since reverted) against the expert reward on the ITN for 300k env-steps, seeds 1-3. The expert's
# three runs were copied from the one-scale comparison (../../at_300k/command.sh: same network,
# seeds and budget), so only the generated runs trained here. ITSKILL_HOME held the shipped library.
set -euo pipefail
mkdir -p runs/pp300k_2s && cp -r runs/pp300k/expert_seed{1,2,3} runs/pp300k_2s/
python benchmarks/reward_at_budget.py --reward results/reward_search/pickplace_nut_m12_itn/two_scale/best_reward.py \
  --workers 3 --out runs/pp300k_2s --results results/reward_search/pickplace_nut_m12_itn/two_scale/at_300k
