#!/usr/bin/env bash
# The README's first command's learning step (the tiny budget), seed 0, a new skill space.
# 2026-12-07, the project machine (2 vCPUs) while two transfer trainings ran beside it: 4.1 min
# end to end (245 s), with the place skill cloned from its script on turned nuts (commit e2dd838).
# Only the small files of the run
# directory are kept here (the run's paths in them are those of the command below).
set -euo pipefail
ITSKILL_HOME=/work/learn_tiny/home itskill learn "Pick up the nut and place it on the bolt" --budget tiny --out /work/learn_tiny/run
