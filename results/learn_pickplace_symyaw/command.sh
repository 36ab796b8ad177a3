#!/usr/bin/env bash
# The README's main job at its default budget, with the place skill trained on turned nuts and
# the 2 mm approach to the bolt (2026-12-07), each seed on a new skill space. The project
# machine (2 vCPUs), beside two transfer trainings and test runs: the times are not the idle
# machine's. Only the small files of each run directory are kept here (the run's paths in them
# are those of the command below).
set -euo pipefail
for s in 0 1; do
  ITSKILL_HOME=/work/learn_def/home_$s itskill learn "Pick up the nut and place it on the bolt" \
    --seed $s --out /work/learn_def/seed_$s
done
