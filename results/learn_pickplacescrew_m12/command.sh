#!/usr/bin/env bash
# The guide's own command, learned end to end with the default budget, seed 0, a new skill space
# (ITSKILL_HOME pointing at an empty directory), on the project machine (2 vCPUs) with two to
# three other training processes beside it.
set -euo pipefail
itskill learn "Pick up the nut, place it on the bolt and screw it down" --seed 0 --out runs/learn_pps/seed0
# The sources run one after another, no training (source_chain.json):
python benchmarks/source_chaining.py pickplacescrew_nut_m12 --chain pick_nut_m12 pick_nut_m12 \
  pick_nut_m12 place_nut_m12 place_nut_m12 screw_nut_m12 --episodes 100 --handovers 40 \
  --json results/learn_pickplacescrew_m12/source_chain.json
