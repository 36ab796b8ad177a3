#!/usr/bin/env bash
# The guide's command end to end at the task's settings of the day (log-std -2.0, PPO 3e-5, 1e-5 since;
# [nutbolt.tasks.pickplacescrew_nut_m12] in src/itskill/rl/data/hyperparams.toml), the default
# budget, each seed in a new skill space (so a seed's new skill is not retrieved as a source by
# the next). 2026-12-05, the project machine (2 vCPUs), beside other training runs and the test
# suite, so the wall times in the reports are upper bounds. Only the small files of each run
# directory are kept here (reports, evaluation, curves, the chosen reward, the video).
set -euo pipefail
for seed in 0 1 2; do
  ITSKILL_HOME=runs/learn_pps_home$seed itskill learn \
    "Pick up the nut, place it on the bolt and screw it down" --seed $seed --out runs/learn_pps/seed$seed
done
