#!/bin/bash
# The chain of ITN's sources alone on the 200 held-out episodes, each skill shown the target's
# stage mapped onto its own as the transfer network shows it (--target-stage), with the stages
# that hold through the insertion. 2026-12-07, the project machine, beside the run: 162 of 200
# (81%), episode for episode the same as with each skill's own stages
# (results/peg_chain/chain_rect_heldout_200_handovers_stages_hold.json).
set -euo pipefail
python benchmarks/source_chaining.py pickplaceinsert_peg_rect \
    --chain pick_peg_rect pick_peg_rect pick_peg_rect place_peg_rect place_peg_rect insert_peg_rect \
    --episodes 200 --target-stage \
    --json results/validation_2core_peg_stages/sources_chain/chain_heldout_200_target_stage.json
