#!/usr/bin/env bash
# itskill learn on the rectangular peg's pick-place-insert (the tiny budget), seed 0, a new
# skill space, after the task's stages were made to hold through the insertion (commit
# 3885665 and after). 2026-12-07, the project machine (2 vCPUs) beside a two-cell experiment:
# 2.9 min by the run's record (174 s; 214 s with the interpreter's start and the imports). 76.0% [62.6%, 85.7%] of 50 held-out episodes. Only the small
# files of the run directory are kept here (the run's paths in them are those of the command
# below).
set -euo pipefail
ITSKILL_HOME=/work/learn_peg/home itskill learn \
    "Pick up the rectangular peg and insert it into the rectangular hole" \
    --budget tiny --seed 0 --out /work/learn_peg/tiny
