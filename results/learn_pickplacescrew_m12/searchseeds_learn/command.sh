#!/usr/bin/env bash
# The guide's command end to end after `--seed` reached the reward search (each seed's search
# trains on its own seeds; seed 0's is unchanged, see ../lr1e5_learn/seed0), the default budget,
# a new skill space per seed. 2026-12-05, the project machine (2 vCPUs), seed 1 then seed 2, with
# tests and reviews sharing the machine part of the time. Only the small files of each run
# directory are kept here.
set -euo pipefail
for seed in 1 2; do
  ITSKILL_HOME=runs/learn_searchseeds_home$seed itskill learn \
    "Pick up the nut, place it on the bolt and screw it down" --seed $seed --out runs/learn_searchseeds/seed$seed
done
