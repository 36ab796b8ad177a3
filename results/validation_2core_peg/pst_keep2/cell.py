"""Train one transfer run exactly as an experiment cell does (n_threads=1, offline analyzer),
with a transfer settings file of our own: python cell.py METHOD SEED OUT [CONFIG.toml]."""

import sys
from pathlib import Path

from itskill.llm import make_client
from itskill.transfer import train_transfer
from itskill.transfer.config import load_transfer_config

method, seed, out = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
config = load_transfer_config(sys.argv[4]) if len(sys.argv) > 4 else None
res = train_transfer(
    "pickplaceinsert_peg_rect",
    method,
    sources=["pick_peg_rect", "place_peg_rect", "insert_peg_rect"],
    seed=seed,
    steps=500_000,
    algo="ppo",
    out=out,
    reward="expert",
    num_envs=16,
    eval_every=50_000,
    eval_episodes=40,
    n_threads=1,
    client=make_client("offline", cache_dir=out.parent / "llm_cache"),
    config=config,
    progress=False,
)
print(out, res.num_timesteps, res.best)
