#!/bin/bash
# PST with two of the three sources (pick_peg_rect, place_peg_rect; insert_peg_rect left out) on
# the peg half's settings (cell.py: PPO at the task's 3e-5, expert reward, 500k env-steps, 40
# evaluation episodes every 50k, n_threads 1 as an experiment cell), seeds 0-2, two at a time
# (seeds 0 and 1 beside two other training jobs, seed 2 beside one).
cd "$(dirname "$0")"
run() {
  ITSKILL_HOME="$PWD/home" python \
    cell.py pst "$1" "runs/seed_$1" transfer_pst2.toml > "log_pst2_$1.txt" 2>&1
}
export -f run
printf '%s\n' 0 1 2 | xargs -P 2 -I{} bash -c 'run {}'
