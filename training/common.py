"""Shared plumbing of the training scripts: argument errors, env ids, run folders, atomic writes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym

from sim_core.files import atomic_path

ALGORITHMS = ("ppo", "sac", "td3")
HYPERPARAMS = Path(__file__).parent / "hyperparams"


class UsageError(Exception):
    """Bad command-line input: reported on one line with exit code 2."""


def fail(program: str, message: str) -> None:
    sys.stderr.write(f"{program}: error: {message}\n")
    raise SystemExit(2)


def make_env(env_id: str, **kwargs):
    """gym.make that registers the tissue tasks first (SubprocVecEnv workers start fresh)."""
    import tissue_env  # noqa: F401

    return gym.make(env_id, **kwargs)


def check_env_id(env_id: str) -> str:
    import tissue_env  # noqa: F401  (registers the tasks)

    if env_id not in gym.registry:
        tissue = sorted(k for k in gym.registry if k.startswith("tissue_env/"))
        raise UsageError(f"unknown environment id {env_id!r}; registered tissue tasks: {', '.join(tissue)}")
    return env_id


def parse_env_kwargs(text: str) -> dict:
    """The --env-kwargs argument: a JSON object of environment constructor keywords."""
    try:
        env_kwargs = json.loads(text)
    except json.JSONDecodeError as error:
        raise UsageError(f"--env-kwargs must be a JSON object: {error}") from error
    if not isinstance(env_kwargs, dict):
        raise UsageError("--env-kwargs must be a JSON object")
    return env_kwargs


def check_algo(algo: str) -> str:
    if algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {algo!r}; choose one of {', '.join(ALGORITHMS)}")
    return algo


def algorithm_class(algo: str):
    from stable_baselines3 import PPO, SAC, TD3

    return {"ppo": PPO, "sac": SAC, "td3": TD3}[check_algo(algo)]


def load_hyperparams(algo: str, env_id: str, config: str | None = None) -> dict:
    """Hyperparameters for (algo, env id): the env's entry of hyperparams/<algo>.yml (or of
    ``config``) on top of its ``default`` entry."""
    import yaml

    path = Path(config) if config else HYPERPARAMS / f"{algo}.yml"
    if not path.is_file():
        raise UsageError(f"hyperparameter file {path} does not exist")
    table = yaml.safe_load(path.read_text()) or {}
    if not isinstance(table, dict):
        raise UsageError(f"{path} must map environment ids to hyperparameters")
    merged = dict(table.get("default", {}))
    merged.update(table.get(env_id, {}))
    return merged


def run_name(env_id: str) -> str:
    return env_id.replace("/", "_")


def write_json(path: Path, data, **dump_options) -> None:
    """Write ``data`` as JSON to ``path`` atomically (``sim_core.files.atomic_path``: a crash or an
    interrupted run never leaves half a file, two writers never share a temporary, mode 0644).
    ``dump_options`` go to ``json.dump`` (default ``indent=2``, ``default=str``). The training
    scripts and the benchmarks write their results with it."""
    with atomic_path(path) as temporary, open(temporary, "w") as stream:
        json.dump(data, stream, **{"indent": 2, "default": str, **dump_options})
        stream.write("\n")
