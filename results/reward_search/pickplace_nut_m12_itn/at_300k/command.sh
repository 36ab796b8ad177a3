#!/usr/bin/env bash
# The chosen pick-and-place reward (../best_reward.py) against the expert reward, each trained
# on the ITN over the retrieved sources for 300,000 env-steps (the `itskill learn` default
# budget's training), seeds 1-3, two runs at a time on the project machine (2 vCPUs), then each
# run's best/ policy on 100 held-out episodes. A fresh ITSKILL_HOME holds the shipped library.
set -euo pipefail
for s in 1 2 3; do
  for r in generated expert; do
    rew=$([ $r = generated ] && echo results/reward_search/pickplace_nut_m12_itn/best_reward.py || echo expert)
    itskill transfer train pickplace_nut_m12 --method itn --sources auto --seed $s --algo ppo \
      --steps 300000 --reward $rew --eval-every 20000 --eval-episodes 50 --out runs/pp300k/${r}_seed$s &
  done
  wait
done
for s in 1 2 3; do for r in generated expert; do
  itskill eval pickplace_nut_m12 --policy runs/pp300k/${r}_seed$s/best --episodes 100 --seed 10000 \
    --json > runs/pp300k/${r}_seed$s.eval.json
done; done
