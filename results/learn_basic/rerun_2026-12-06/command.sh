#!/usr/bin/env bash
# The learning-speed benchmark of docs/training.md run again on the code of 74ebe89 (2026-12-06),
# same command and settings as results/learn_basic/summary.json (2026-11-22). The project machine
# (2 vCPUs), two runs at a time; read-only review helpers and test runs shared the machine part of
# the time, so the wall-minutes are upper bounds: compare env-steps.
set -euo pipefail
python benchmarks/learn_basic.py --tasks pick_nut_m12 --steps 200000 --a2c-steps 300000 --workers 2 \
  --out runs/learn_basic_rerun
