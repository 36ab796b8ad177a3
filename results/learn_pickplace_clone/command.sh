#!/usr/bin/env bash
# The README's main job at its default budget with the shipped library of 2026-12-07, later:
# place_nut_m12 cloned from its script on turned nuts (docs/skills.md, "Twenty-fifth
# pretraining"), seed 0, a new skill space, commit e2dd838. The project machine (2 vCPUs), beside
# one or two transfer trainings: 24 minutes, not the idle machine's time. Only the small files
# of the run directory are kept here (the run's paths in them are those of the command below).
set -euo pipefail
ITSKILL_HOME=/work/learn_clone/home_0 itskill learn "Pick up the nut and place it on the bolt" \
  --seed 0 --out /work/learn_clone/seed_0
# Seed 1 the same way on the idle machine, code of eff91f2: 13.9 minutes end to end.
ITSKILL_HOME=/work/learn_clone/home_1 itskill learn "Pick up the nut and place it on the bolt" \
  --seed 1 --out /work/learn_clone/seed_1
