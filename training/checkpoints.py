"""Checkpoints, evaluations and the run record of training.train, written so that a run killed at
any moment (SIGKILL included) resumes without loss.

Every file goes to a temporary name in its destination's folder and is renamed onto it
(``sim_core.files.atomic_path``): a reader sees the old file or the new one, never half of one.
A checkpoint is the VecNormalize statistics, the replay buffer (off-policy) and then the model zip
of one step; the model zip is written last, so a checkpoint is listed only once it is complete.

When a checkpoint is taken (``Checkpoints``): at the start of a rollout and at the end of
training, i.e. after the update that the previous rollout fed. On-policy (PPO) every counted
step has then been trained on; off-policy (SAC, TD3) the step's transition has been stored (SB3
calls ``on_step`` before it stores a step's transition, so a checkpoint in ``on_step`` holds one
transition fewer than its step count).

``pick_checkpoint`` tries the checkpoints newest first and returns the first that loads; one that
does not (0 bytes, a truncated zip, an unpicklable pickle, a missing part) is skipped with a
printed line naming the file and the reason.
"""

from __future__ import annotations

import os
import pickle
import re
import threading
import time
from pathlib import Path

import numpy as np

from sim_core.files import atomic_path

from .common import load_model, write_json

CHECKPOINT_GLOB = "model_*_steps.zip"
#: replay buffers kept (one is up to buffer_size transitions: tens of MB); two, so that a damaged
#: newest checkpoint still leaves an older one with its buffer
KEEP_BUFFERS = 2


def steps_of(path: Path) -> int:
    """The env steps in a checkpoint file's name (model_<steps>_steps.zip, model_replay_buffer_<steps>_steps.pkl)."""
    return int(re.search(r"_(\d+)_steps", Path(path).name).group(1))


def model_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"model_{step}_steps.zip"


def vecnormalize_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"model_vecnormalize_{step}_steps.pkl"


def buffer_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"model_replay_buffer_{step}_steps.pkl"


# ----------------------------------------------------------------------------- atomic writes
def save_model(model, path: Path) -> Path:
    """``model.save`` to a temporary ``.zip`` beside ``path``, renamed onto it."""
    with atomic_path(path) as temporary:
        model.save(str(temporary))
    return Path(path)


def save_vecnormalize(vec_normalize, path: Path) -> Path:
    """``VecNormalize.save`` (a pickle without its venv) atomically."""
    with atomic_path(path) as temporary:
        vec_normalize.save(str(temporary))
    return Path(path)


def save_replay_buffer(model, path: Path) -> Path:
    """The model's replay buffer pickled atomically (SB3's ``save_to_pkl`` format)."""
    with atomic_path(path) as temporary, open(temporary, "wb") as stream:
        pickle.dump(model.replay_buffer, stream, protocol=pickle.HIGHEST_PROTOCOL)
    return Path(path)


def save_evaluations(path: Path, evaluations: dict) -> Path:
    """``evaluations.npz`` (timesteps, results, ep_lengths as EvalCallback writes them) atomically."""
    with atomic_path(path) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, **{key: np.asarray(value) for key, value in evaluations.items()})
    return Path(path)


def load_evaluations(path: Path, up_to: int | None = None) -> tuple[dict, list[int]]:
    """The evaluations of ``path`` (empty lists without one) with timesteps <= ``up_to``, and the
    timesteps of those dropped (evaluations of a model the resumed run rewinds past)."""
    evaluations = dict(timesteps=[], results=[], ep_lengths=[])
    path = Path(path)
    if not path.is_file():
        return evaluations, []
    try:
        with np.load(path) as data:
            loaded = {key: [row for row in data[key]] for key in evaluations}
    except Exception as error:  # noqa: BLE001 -- a damaged file is reported, the run goes on
        print(f"ignoring {path}: cannot be read ({type(error).__name__}: {error})", flush=True)
        return evaluations, []
    keep = [i for i, step in enumerate(loaded["timesteps"]) if up_to is None or int(step) <= up_to]
    dropped = [int(step) for step in loaded["timesteps"] if up_to is not None and int(step) > up_to]
    return {key: [loaded[key][i] for i in keep] for key in evaluations}, dropped


# ----------------------------------------------------------------------------- the picker
def pick_checkpoint(folder: Path, load, log=print):
    """The newest checkpoint of ``folder`` that ``load(step)`` loads: ``(step, loaded, skipped)``,
    or ``(None, None, skipped)`` when none does. ``load`` raises on a checkpoint it cannot use;
    each one skipped is reported with ``log`` and listed in ``skipped`` as {file, step, reason}."""
    skipped = []
    paths = sorted(Path(folder).glob(CHECKPOINT_GLOB), key=steps_of, reverse=True) if Path(folder).is_dir() else []
    for path in paths:
        step = steps_of(path)
        try:
            loaded = load(step)
        except Exception as error:  # noqa: BLE001 -- anything that fails to load is skipped
            name = getattr(error, "filename", None) or str(path)
            reason = str(error) if isinstance(error, CheckpointError) else f"{type(error).__name__}: {error}"
            log(f"skipping checkpoint {Path(name).name} (step {step}): {reason}")
            skipped.append(dict(file=str(Path(name).name), step=step, reason=reason))
            continue
        return step, loaded, skipped
    return None, None, skipped


class CheckpointError(Exception):
    """A part of a checkpoint that cannot be used (``filename``: the file)."""

    def __init__(self, message: str, filename: Path):
        super().__init__(message)
        self.filename = str(filename)


def checkpoint_loader(folder: Path, algo_cls, normalize: bool, off_policy: bool, n_envs: int, **load_kwargs):
    """``load(step)`` for ``pick_checkpoint``: the model (without env), the VecNormalize statistics
    (when the run normalises) and the replay buffer (off-policy; it must hold ``step``
    transitions) of one step, each checked to load."""

    def load(step: int):
        zip_path = model_path(folder, step)
        if zip_path.stat().st_size == 0:
            raise CheckpointError("empty file (0 bytes)", zip_path)
        try:
            model = load_model(algo_cls, str(zip_path), **load_kwargs)
        except Exception as error:
            raise CheckpointError(f"{type(error).__name__}: {error}", zip_path) from error
        if model.num_timesteps != step:
            raise CheckpointError(f"holds {model.num_timesteps} steps, its name says {step}", zip_path)
        stats = None
        if normalize:
            stats_path = vecnormalize_path(folder, step)
            stats = _unpickle(stats_path)
        if off_policy:
            replay = buffer_path(folder, step)
            buffer = _unpickle(replay)
            transitions = int(buffer.size()) * int(getattr(buffer, "n_envs", n_envs))
            if transitions != step and not buffer.full:
                raise CheckpointError(f"holds {transitions} transitions, the checkpoint step is {step}", replay)
            model.replay_buffer = buffer
            buffer.device = model.device
        return model, stats

    return load


def _unpickle(path: Path):
    if not path.is_file():
        raise CheckpointError("missing", path)
    if path.stat().st_size == 0:
        raise CheckpointError("empty file (0 bytes)", path)
    try:
        with open(path, "rb") as stream:
            return pickle.load(stream)
    except Exception as error:
        raise CheckpointError(f"cannot be unpickled ({type(error).__name__}: {error})", path) from error


# ----------------------------------------------------------------------------- callbacks
def callbacks(run_dir: Path, checkpoint_freq: int, eval_env, eval_freq: int, eval_episodes: int,
              evaluations: dict, record, start_step: int):
    """The run's callbacks: atomic checkpoints at rollout boundaries and atomic, accumulating
    evaluations on the schedule of an uninterrupted run (every ``eval_freq`` env steps)."""
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import sync_envs_normalization

    folder = Path(run_dir) / "checkpoints"

    class Checkpoints(BaseCallback):
        """A checkpoint at the first rollout boundary at or after every ``checkpoint_freq`` steps
        (and at the end of training)."""

        def __init__(self):
            super().__init__()
            self.last = start_step

        def _save(self):
            step = int(self.model.num_timesteps)
            if step == self.last:
                return
            folder.mkdir(parents=True, exist_ok=True)
            normaliser = self.model.get_vec_normalize_env()
            if normaliser is not None:
                save_vecnormalize(normaliser, vecnormalize_path(folder, step))
            if hasattr(self.model, "replay_buffer") and self.model.replay_buffer is not None:
                save_replay_buffer(self.model, buffer_path(folder, step))
            save_model(self.model, model_path(folder, step))  # last: the checkpoint is complete
            self.last = step
            # the newest buffers up to this step stay (newer ones, of checkpoints a resume skipped, are
            # overwritten when the run gets there)
            buffers = sorted((b for b in folder.glob("model_replay_buffer_*_steps.pkl") if steps_of(b) <= step),
                             key=steps_of)
            for old in buffers[:-KEEP_BUFFERS]:
                old.unlink(missing_ok=True)
            record.checkpointed(step)

        def _on_rollout_start(self) -> None:
            if self.model.num_timesteps // checkpoint_freq > self.last // checkpoint_freq:
                self._save()

        def _on_step(self) -> bool:
            return True

        def _on_training_end(self) -> None:
            self._save()

    class Evaluations(BaseCallback):
        """EvalCallback's evaluation (normaliser synchronised, deterministic actions) whenever the
        step count passes a multiple of ``eval_freq``, appended to ``evaluations`` and written
        atomically."""

        def __init__(self):
            super().__init__()
            self.last = start_step  # the evaluations up to the start step are in ``evaluations``

        def _on_step(self) -> bool:
            step = int(self.num_timesteps)
            if step // eval_freq > self.last // eval_freq:
                if self.model.get_vec_normalize_env() is not None:
                    sync_envs_normalization(self.training_env, eval_env)
                returns, lengths = evaluate_policy(self.model, eval_env, n_eval_episodes=eval_episodes,
                                                   deterministic=True, return_episode_rewards=True)
                evaluations["timesteps"].append(step)
                evaluations["results"].append(np.asarray(returns, dtype=float))
                evaluations["ep_lengths"].append(np.asarray(lengths, dtype=int))
                save_evaluations(Path(run_dir) / "evaluations.npz", evaluations)
                self.last = step
            return True

    return CallbackList([Evaluations(), Checkpoints()])


# ----------------------------------------------------------------------------- the run record
def remove_stale_temporaries(*folders) -> list[Path]:
    """Remove the temporaries of writes a killed session never finished (``atomic_path``'s
    ``.<name>.<random>.tmp<suffix>``); only one session of a run writes at a time."""
    removed = []
    for folder in folders:
        if Path(folder).is_dir():
            for path in Path(folder).glob(".*.tmp*"):
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed


def repair_monitor_logs(folder) -> list[Path]:
    """Cut a partial last line (a session killed while SB3's Monitor wrote a row) from the
    monitor CSVs of ``folder``, so that the resumed run appends whole rows after whole rows."""
    repaired = []
    for path in sorted(Path(folder).glob("*.monitor.csv")) if Path(folder).is_dir() else []:
        data = path.read_bytes()
        if data and not data.endswith(b"\n"):
            with open(path, "r+b") as stream:
                stream.truncate(data.rfind(b"\n") + 1)
            repaired.append(path)
    return repaired


def truncate_monitor_logs(folder, step: int, n_envs: int, batched: bool = False) -> dict[str, int]:
    """Keep in the monitor CSVs of ``folder`` the episodes that end at or before a checkpoint of
    ``step`` env steps, so that the episodes of the steps a resumed run trains again are not in the
    learning curve twice. An episode's end is the cumulative sum of the episode lengths (``l``) in its
    file: a file per env (SB3's Monitor: ``step / n_envs`` steps each, the envs step in lockstep), or
    one file of every env's episodes (``batched``: the VecMonitor of the batched vector env; the
    lengths of its episodes up to the checkpoint sum to at most ``step``). Each file is rewritten
    atomically; returns {file name: rows dropped} of the files cut."""
    limit = int(step) if batched else int(step) // max(int(n_envs), 1)
    cut = {}
    for path in sorted(Path(folder).glob("*.monitor.csv")) if Path(folder).is_dir() else []:
        lines = path.read_text().splitlines(keepends=True)
        header = [line for line in lines[:2] if line.startswith("#") or line.startswith("r,")]
        rows = lines[len(header):]
        if len(header) < 2 or not rows:
            continue
        column = header[1].strip().split(",").index("l")
        total, keep = 0, 0
        for row in rows:
            total += int(float(row.split(",")[column]))
            if total > limit:
                break
            keep += 1
        if keep < len(rows):
            with atomic_path(path) as temporary:
                temporary.write_text("".join(header + rows[:keep]))
            cut[path.name] = len(rows) - keep
    return cut


def process_start_time() -> float:
    """This process's start (seconds since the epoch; from /proc, else now): a session's wall
    clock includes the interpreter's start and the imports."""
    try:  # its age: the system's uptime less the process's start after boot (both to 1/100 s)
        ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        age = uptime - ticks / os.sysconf("SC_CLK_TCK")
        if 0 <= age < 3600:
            return time.time() - age
    except Exception:  # noqa: BLE001
        pass
    return time.time()


#: Whether a run's session has started in this process: the first one's wall clock counts from the
#: process's start (the interpreter and the imports are its cost), a later one's (``training.benchmark``
#: trains its runs one after the other in one process) from its own start, not the earlier runs' time.
_SESSION_STARTED = False


def session_start_time() -> float:
    """The start (seconds since the epoch) of a run's session made now: ``process_start_time`` for
    the process's first session, the current time for the next ones."""
    global _SESSION_STARTED
    first, _SESSION_STARTED = not _SESSION_STARTED, True
    return process_start_time() if first else time.time()


class RunRecord:
    """result.json, kept current while the run trains: ``timesteps`` (the latest checkpoint, the
    final count once finished), ``wall_clock_s`` (the sum over the run's sessions, a killed one
    counted to its last heartbeat), ``sessions``, ``resumes`` (step, skipped files, evaluations
    dropped) and ``finished``. A heartbeat thread rewrites it every ``heartbeat`` seconds."""

    def __init__(self, path: Path, heartbeat: float = 0.2):
        import json

        self.path = Path(path)
        self.lock = threading.Lock()
        previous = {}
        if self.path.is_file():
            try:
                previous = json.loads(self.path.read_text())
            except ValueError:
                previous = {}
        self.sessions = list(previous.get("sessions", []))
        for session in self.sessions:
            if session.get("status") == "running":  # it never finished: killed, its time counted to its last heartbeat
                session["status"] = "interrupted"
        if not self.sessions and "wall_clock_s" in previous:  # a record written before sessions were kept
            self.sessions.append(dict(wall_s=float(previous["wall_clock_s"]), start_step=0,
                                      end_step=previous.get("timesteps"), status="finished"))
        self.resumes = list(previous.get("resumes", []))
        self.timesteps = previous.get("timesteps", 0)
        self.resumed_from = previous.get("resumed_from")
        self.start = session_start_time()
        self.session = dict(started=time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(self.start)), wall_s=0.0,
                            start_step=0, end_step=0, status="running")
        self.sessions.append(self.session)
        self.finished = False
        self.heartbeat = heartbeat
        self._stop = threading.Event()
        self._thread = None

    def open(self):
        """Write the record now and then every ``heartbeat`` seconds (so that a killed session's
        time is counted to within a heartbeat)."""
        with self.lock:
            self._write()
        self._thread = threading.Thread(target=self._beat, name="run-record", daemon=True)
        self._thread.start()

    def begin(self, start_step: int, resume: dict | None):
        """The session trains from ``start_step``; ``resume``: its resume event (step, skipped files, ...)."""
        with self.lock:
            self.session["start_step"] = self.session["end_step"] = int(start_step)
            if resume is not None:
                self.resumes.append(resume)
                self.resumed_from = resume["step"]
            self._write()

    def _beat(self):
        while not self._stop.wait(self.heartbeat):
            with self.lock:
                self._write()

    def checkpointed(self, step: int):
        with self.lock:
            self.timesteps = self.session["end_step"] = int(step)
            self._write()

    def finish(self, timesteps: int):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with self.lock:
            self.timesteps = self.session["end_step"] = int(timesteps)
            self.session["status"] = "finished"
            self.finished = True
            self._write()

    def _write(self):
        self.session["wall_s"] = time.time() - self.start
        write_json(self.path, dict(
            timesteps=int(self.timesteps), wall_clock_s=sum(float(s["wall_s"]) for s in self.sessions),
            finished=self.finished, resumed_from=self.resumed_from, resumes=self.resumes, sessions=self.sessions))
