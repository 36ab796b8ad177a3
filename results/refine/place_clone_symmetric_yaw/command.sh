#!/bin/bash
# place_nut_m12 trained again from a clone of the scripted place on its start with the nut turned
# by any multiple of 60 degrees (symmetric_yaw), instead of refined from the skill trained before
# the turn (../place_symmetric_yaw/): 500 scripted episodes cloned, then PPO for 100k env-steps,
# the policy of the best 50-episode evaluation kept and measured on the task's 400 held-out
# episodes; then, as the place source of the pick-and-place chain (pick x3, place x2), on its 200
# held-out episodes, each skill seeing its own task's stage and then the target's stage mapped
# onto its own (as the transfer network shows them). Project machine (2 vCPUs), 2026-12-07,
# beside two experiment cells. The skill is the shipped place_nut_m12 (its library entry copied
# into the package's).
set -euo pipefail
export ITSKILL_HOME=home1
itskill skills pretrain --tasks place_nut_m12 --steps 100000 --seeds 1 --seed 1 --eval-every 20000 \
    --workers 1 --runs runs1
for STAGE in "" --target-stage; do
  python benchmarks/source_chaining.py pickplace_nut_m12 \
      --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
      --episodes 200 $STAGE \
      --json results/refine/place_clone_symmetric_yaw/chain_heldout_200${STAGE:+_target_stage}_seed1.json
done
# Later the same day: both place skills under the noise a transfer target at log-std -3.0 adds
# (sigma 0.05 on every action), target's stages; the refined skill (Twenty-fourth pretraining)
# from the code and library of commit 69fcf26 (a worktree there, a new skill space).
python benchmarks/source_chaining.py pickplace_nut_m12 \
    --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --target-stage --noise 0.05 \
    --json results/refine/place_clone_symmetric_yaw/chain_heldout_200_target_stage_noise0.05_seed1.json
git worktree add --detach ../itskill-69fcf26 69fcf26
ITSKILL_HOME=home_refined PYTHONPATH=../itskill-69fcf26/src python ../itskill-69fcf26/benchmarks/source_chaining.py \
    pickplace_nut_m12 --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --target-stage --noise 0.05 \
    --json results/refine/place_clone_symmetric_yaw/chain_heldout_200_target_stage_noise0.05_refined.json
