"""Shared plumbing of the training scripts: argument errors, env ids, run folders, atomic writes."""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import contextmanager
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


class CommandParser(argparse.ArgumentParser):
    """The argument parser of ``python -m <program>``: its errors are reported by ``fail``."""

    def __init__(self, program: str, **options):
        super().__init__(prog=f"python -m {program}", **options)
        self.program = program

    def error(self, message):
        fail(self.program, message)


@contextmanager
def usage_errors(program: str):
    """A ``UsageError`` raised in the block is reported by ``fail`` (one line, exit code 2)."""
    try:
        yield
    except UsageError as error:
        fail(program, str(error))


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


def check_env_kwargs(env_id: str, env_kwargs: dict) -> dict:
    """Make ``env_id`` once with ``env_kwargs`` (and close it): a keyword the environment does not
    take, or a value it refuses, is a ``UsageError`` before a run folder is made. Without keywords
    nothing is built (the environment's defaults)."""
    if not env_kwargs:
        return env_kwargs
    try:
        env = make_env(env_id, **env_kwargs)
    except Exception as error:  # noqa: BLE001 -- whatever the constructor raises is the user's input error
        reason = (str(error).strip().splitlines() or [""])[0]
        raise UsageError(f"--env-kwargs {json.dumps(env_kwargs)} rejected by {env_id}: "
                         f"{type(error).__name__}: {reason}") from error
    env.close()
    return env_kwargs


def check_algo(algo: str) -> str:
    if algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {algo!r}; choose one of {', '.join(ALGORITHMS)}")
    return algo


def algorithm_class(algo: str):
    from stable_baselines3 import PPO, SAC, TD3

    return {"ppo": PPO, "sac": SAC, "td3": TD3}[check_algo(algo)]


#: rl_zoo3 keys of a hyperparameter entry that training.train does not implement (it refuses
#: them rather than train without them).
UNSUPPORTED_ZOO_KEYS = ("env_wrapper", "vec_env_wrapper", "frame_stack", "callback", "normalize_kwargs")
#: rl_zoo3 exploration noise types and the stable-baselines3 classes (training.train builds them).
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")


def load_hyperparams(algo: str, env_id: str, config: str | None = None) -> dict:
    """Hyperparameters for (algo, env id) from hyperparams/<algo>.yml (or ``config``).

    The files are in rl_zoo3's format: one entry per environment id with ``n_timesteps``,
    ``policy``, the rl_zoo3 keys ``n_envs``, ``normalize`` (true, or a mapping of VecNormalize
    keywords) and ``noise_type`` / ``noise_std`` (off-policy exploration), and the algorithm's
    constructor keywords (``replay_buffer_class`` by name, e.g. ``HerReplayBuffer`` with
    ``policy: MultiInputPolicy`` on a goal observation). The entry is read on top of a ``default`` entry (the files' YAML anchor,
    which their entries also merge with ``<<: *default``; a file of only ``default`` applies to
    every id). ``policy_kwargs`` and ``normalize`` must be YAML mappings, not rl_zoo3's Python
    strings, and the rl_zoo3 keys in ``UNSUPPORTED_ZOO_KEYS`` are refused."""
    import yaml

    path = Path(config) if config else HYPERPARAMS / f"{algo}.yml"
    if not path.is_file():
        raise UsageError(f"hyperparameter file {path} does not exist")
    try:
        table = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as error:
        raise UsageError(f"{path} is not valid YAML: {error}") from error
    if not isinstance(table, dict) or not all(isinstance(entry, dict) for entry in table.values()):
        raise UsageError(f"{path} must map environment ids to mappings of hyperparameters")
    if env_id not in table and "default" not in table:
        raise UsageError(f"{path} has no entry for {env_id} (and no default); its ids: {', '.join(table)}")
    merged = dict(table.get("default", {}))
    merged.update(table.get(env_id, {}))
    unsupported = [key for key in UNSUPPORTED_ZOO_KEYS if key in merged]
    if unsupported:
        raise UsageError(f"{path} [{env_id}]: rl_zoo3 key(s) {', '.join(unsupported)} not supported by the "
                         "training scripts")
    for key in ("policy_kwargs", "normalize", "replay_buffer_kwargs"):
        if isinstance(merged.get(key), str):
            raise UsageError(f"{path} [{env_id}]: write {key} as a YAML mapping (e.g. {{net_arch: [64, 64]}}), "
                             f"not as a Python string ({merged[key]!r})")
    if merged.get("replay_buffer_class") is not None:
        replay_buffer_class(merged["replay_buffer_class"], f"{path} [{env_id}]")
    if merged.get("noise_type") is not None and merged["noise_type"] not in NOISE_TYPES:
        raise UsageError(f"{path} [{env_id}]: noise_type must be one of {', '.join(NOISE_TYPES)}, "
                         f"got {merged['noise_type']!r}")
    return merged


#: Replay buffers a hyperparameter file may name (``replay_buffer_class``), as stable-baselines3 exports them.
REPLAY_BUFFERS = ("ReplayBuffer", "DictReplayBuffer", "HerReplayBuffer")


def replay_buffer_class(name, where: str = "replay_buffer_class"):
    """The stable-baselines3 replay buffer class called ``name`` (``REPLAY_BUFFERS``); UsageError otherwise."""
    if not isinstance(name, str) or name not in REPLAY_BUFFERS:
        raise UsageError(f"{where}: replay_buffer_class must be one of {', '.join(REPLAY_BUFFERS)}, got {name!r}")
    import stable_baselines3
    from stable_baselines3.common import buffers

    return getattr(stable_baselines3, name, None) or getattr(buffers, name)


def load_model(algo_cls, path, **load_kwargs):
    """``algo_cls.load(path, **load_kwargs)`` that also loads a model trained with a
    ``HerReplayBuffer``: stable-baselines3 rebuilds such a buffer only with an env to compute its
    rewards, which an evaluation or a checkpoint's load (the env comes later) does not pass. The model is
    loaded with an empty ``DictReplayBuffer`` and its HER class and keywords restored as attributes:
    an evaluation only predicts, a resume puts the checkpoint's HER buffer back and gives it the env."""
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.buffers import DictReplayBuffer
    from stable_baselines3.common.save_util import load_from_zip_file

    data = load_from_zip_file(path, device=load_kwargs.get("device", "auto"), load_data=True)[0]
    her = isinstance(data.get("replay_buffer_class"), type) and issubclass(data["replay_buffer_class"], HerReplayBuffer)
    if not her:
        return algo_cls.load(path, **load_kwargs)
    custom = dict(load_kwargs.pop("custom_objects", None) or {}, replay_buffer_class=DictReplayBuffer,
                  replay_buffer_kwargs={})
    model = algo_cls.load(path, custom_objects=custom, **load_kwargs)
    model.replay_buffer_class = data["replay_buffer_class"]
    model.replay_buffer_kwargs = data.get("replay_buffer_kwargs") or {}
    return model


def action_noise(hyperparams: dict, n_actions: int):
    """Pop the exploration-noise keys from ``hyperparams`` and return stable-baselines3's noise:
    rl_zoo3's ``noise_type`` (normal, ornstein-uhlenbeck) and ``noise_std``, or the older
    ``action_noise_std`` (normal) of runs saved before the files followed rl_zoo3; None without."""
    import numpy as np

    noise_type = hyperparams.pop("noise_type", None)
    noise_std = hyperparams.pop("noise_std", None)
    legacy = hyperparams.pop("action_noise_std", None)
    if noise_type is None and legacy is not None:
        noise_type, noise_std = "normal", legacy
    if noise_type is None:
        return None
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    sigma = float(0.1 if noise_std is None else noise_std) * np.ones(n_actions)
    cls = NormalActionNoise if noise_type == "normal" else OrnsteinUhlenbeckActionNoise
    return cls(mean=np.zeros(n_actions), sigma=sigma)


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
