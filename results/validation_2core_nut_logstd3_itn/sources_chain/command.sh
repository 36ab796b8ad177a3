#!/bin/bash
# The chain of ITN's sources alone (no learning; the skill performing each stage acts, as the
# source-action residual's performers are: pick for stages 1-3, place for 4-5) on the 200
# held-out episodes `itskill experiment held-out` measures the runs on (seed 10,000, 25
# environments), without noise and with log-std -3.0's (exp(-3) = 0.0498). 2026-12-06, the
# project machine (2 vCPUs), beside the No_Transfer runs.
set -euo pipefail
python benchmarks/source_chaining.py pickplace_nut_m12 \
    --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --json results/validation_2core_nut_logstd3_itn/sources_chain/chain_heldout_200.json
python benchmarks/source_chaining.py pickplace_nut_m12 \
    --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --noise 0.0498 \
    --json results/validation_2core_nut_logstd3_itn/sources_chain/chain_heldout_200_noise_0.0498.json
# Where the chain's failed episodes lose the nut (the hand-over trace, which now also records
# the moment a held part leaves the fingers; 200 episodes in one batch). 2026-12-06, late night,
# the idle project machine.
python benchmarks/source_chaining.py pickplace_nut_m12 \
    --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --handovers 200 \
    --json results/validation_2core_nut_logstd3_itn/sources_chain/chain_heldout_200_handovers.json
