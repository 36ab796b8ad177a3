#!/usr/bin/env bash
# The generated reward against the expert's on pick-and-place, with today's skill library (the
# place skill cloned from its script on nuts turned by their symmetries, 2026-12-07) and the
# settings of the validation runs (log-std -3.0, PPO 1e-5: hyperparams.toml, the packaged file
# with pickplace_nut_m12's two values changed). 2026-12-07, the project machine (2 vCPUs), code of
# commit 5be8322 (a worktree); two runs at a time, test runs beside them part of the time.
#
# 1. The reward: `itskill learn`'s reward step with the default budget (2 iterations x 4
#    samples at 20,000 env-steps on the ITN over pick_nut_m12, place_nut_m12, carry_nut_m12,
#    the packaged settings), in a fresh skill space, seed 0; learn_budgets.toml is the default
#    budget with a 20k-step transfer training and no expert comparison, since only the chosen
#    reward (best_reward.py) was wanted. 8.6 minutes for the session, 6.8 of them the search.
ITSKILL_HOME=runs/home_learn itskill learn "Pick up the nut and place it on the bolt" \
  --budgets learn_budgets.toml --seed 0 --out runs/learn_pp --no-video
cp runs/learn_pp/reward/best_reward.py runs/learn_pp/reward/summary.json .   # -> reward_search_summary.json
# 2. Both rewards on the ITN for 300k env-steps, seeds 1-4, best/ on 100 held-out episodes. The
#    generated reward ran here as the benchmark then did, as plain Python (the benchmark now
#    trains it in the reward sandbox; the training is the same).
ITSKILL_HOME=runs/home_rab python benchmarks/reward_at_budget.py --task pickplace_nut_m12 \
  --reward results/reward_search/pickplace_nut_m12_itn/current_library/best_reward.py \
  --seeds 1 2 3 4 --workers 2 --out runs/rab_lib --hyperparams \
  results/reward_search/pickplace_nut_m12_itn/current_library/hyperparams.toml \
  --results results/reward_search/pickplace_nut_m12_itn/current_library
# Seeds 5 and 6 were added by two later calls of the same command with --seeds 5 (then 6)
# --with-earlier, which pooled them with the kept seeds into summary.json (the machine idle but
# for them: 9.8 and 10.5 minutes for each pair of runs). Seeds 1-4 took 41.9 minutes, test runs
# beside them part of the time. The runs named the reward and hyper-parameter files by the
# paths they were made at (/work/rab2/learn/reward/best_reward.py, /work/rab2/hyperparams.toml:
# the same bytes as best_reward.py and hyperparams.toml here), which summary.json records and
# --with-earlier compares, so extending this summary needs files at those paths (or a new
# summary without --with-earlier). Seeds 7-10 were added the same way in a later session
# (--seeds 7 8 9 10 --with-earlier, code of commit ae42803 in a worktree, a fresh ITSKILL_HOME
# with the same shipped library; 65.6 minutes for the eight runs, two at a time, with test runs
# and review helpers beside them). output.txt is that last call's summary.
