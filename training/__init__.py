"""stable-baselines3 training, evaluation and plotting for the tissue_env tasks (rl-zoo style).

    python -m training.train --env tissue_env/TumorPositioning-v0 --algo ppo --timesteps 50000 --seed 0
    python -m training.evaluate runs/tissue_env_TumorPositioning-v0/ppo/seed0-20261123-101500 --episodes 20
    python -m training.plot runs/tissue_env_TumorPositioning-v0/ppo/* --out docs/figures/tumor_ppo.png
"""
