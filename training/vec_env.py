"""The stable-baselines3 VecEnv over the batched vector envs, now ``tissue_env.sb3`` (it ships with
the package); re-exported here for the training scripts and older imports."""

from tissue_env.sb3 import BatchedVecEnv, monitored

__all__ = ["BatchedVecEnv", "monitored"]
