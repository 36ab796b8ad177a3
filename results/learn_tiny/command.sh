#!/usr/bin/env bash
# The README's first command's learning step (the tiny budget), seed 0, a new skill space.
# 2026-12-05, the project machine (2 vCPUs) while two transfer trainings ran beside it: 123 s end
# to end. Only the small files of the run directory are kept here.
set -euo pipefail
ITSKILL_HOME=runs/home_tiny itskill learn "Pick up the nut and place it on the bolt" --budget tiny --out runs/learn_tiny
