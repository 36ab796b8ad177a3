#!/usr/bin/env bash
# Pick (round peg) from scratch with every stage needing the peg upright, against the packaged
# task, PPO, seed 0, 300k env-steps, 50 evaluation episodes every 50k (docs/skills.md, "Pick
# (round peg) from scratch, still not learned"). tasks.toml is the packaged pick_peg_round with
# `and upright(0)` added to each stage's `done`, loaded as a user task file.
set -euo pipefail
export ITSKILL_TASKS_DIR=results/pick_peg_round_upright
itskill train pick_peg_round_upright --algo ppo --steps 300000 --seed 0 --eval-every 50000 \
  --eval-episodes 50 --out runs/pick_peg_round_upright/upright
itskill train pick_peg_round --algo ppo --steps 300000 --seed 0 --eval-every 50000 \
  --eval-episodes 50 --out runs/pick_peg_round_upright/packaged
