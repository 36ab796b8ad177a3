#!/bin/bash
# The chain of ITN's sources alone on the 200 held-out episodes, each skill shown the target's
# stage mapped onto its own as the transfer network shows it (--target-stage), with the place
# skill of 2026-12-07 and the 2 mm approach. 2026-12-07, the project machine, beside the run.
set -euo pipefail
python benchmarks/source_chaining.py pickplace_nut_m12 \
    --chain pick_nut_m12 pick_nut_m12 pick_nut_m12 place_nut_m12 place_nut_m12 \
    --episodes 200 --target-stage \
    --json results/validation_2core_nut_symyaw/sources_chain/chain_heldout_200_target_stage.json
