#!/bin/bash
# place_nut_m12 refined on nuts turned by any multiple of 60 degrees in the fingers (the task's
# symmetric_yaw, docs/tasks.md), from the shipped skill, two seeds at once on the project machine
# (2 vCPUs), each in a skill space of its own; then each refined skill as the place source of the
# pick-and-place chain (pick x3, place x2) on the 200 held-out episodes. 2026-12-07.
set -euo pipefail
for S in 1 2; do
  ITSKILL_HOME=home$S itskill skills pretrain --tasks place_nut_m12 --refine --steps 300000 \
      --seeds 1 --seed $S --eval-every 50000 --workers 1 --runs runs$S &
done
wait
for S in 1 2; do
  ITSKILL_HOME=home$S python benchmarks/source_chaining.py pickplace_nut_m12 \
      --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
      --episodes 200 --json results/refine/place_symmetric_yaw/chain_heldout_200_seed$S.json
done
# Seed 1's skill is the shipped place_nut_m12 (its library entry copied into the package's).
