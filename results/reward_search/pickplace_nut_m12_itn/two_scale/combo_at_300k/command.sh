#!/usr/bin/env bash
# ../sample0_at_300k/reward.py with its carry back on one scale (to_fixture_fine removed,
# temp_to_fixture_3 = 0.05, the one-scale recipe's default; edited by hand): the two-scale
# approach and the grasp change alone, against the expert reward on the ITN for 300k
# env-steps, seeds 1-3. Expert runs copied as in ../at_300k/command.sh.
set -euo pipefail
mkdir -p runs/pp300k_combo && cp -r runs/pp300k/expert_seed{1,2,3} runs/pp300k_combo/
python benchmarks/reward_at_budget.py \
  --reward results/reward_search/pickplace_nut_m12_itn/two_scale/combo_at_300k/reward.py \
  --workers 3 --out runs/pp300k_combo --results results/reward_search/pickplace_nut_m12_itn/two_scale/combo_at_300k
