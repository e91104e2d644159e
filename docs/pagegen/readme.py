"""README.md's generated tables: the tasks (from the task classes and tissue_env.ENV_IDS) and
training (from benchmarks/results/training.json), between their markers."""

from __future__ import annotations

import inspect
import re

import numpy as np

from .common import ROOT, load, short_id, table


#: Units of the ``{keyword:unit}`` fields of a task's ``summary`` / ``success_summary``: name -> (factor, suffix)
UNITS = {"mm": (1e3, " mm"), "cm": (1e2, " cm"), "m": (1.0, " m"), "N": (1.0, " N"), "%": (1e2, "%"), "x": (1.0, "x")}


def keyword_default(cls, name):
    """The default of a task keyword: its ``difficulty="default"`` value, else its constructor
    default (the task's, then the base's), else the class attribute ``name`` (e.g. default_size)."""
    level = cls.DIFFICULTY.get("default", {})
    if name in level:
        return level[name]
    for owner in cls.__mro__:
        parameter = inspect.signature(owner.__init__).parameters.get(name) if "__init__" in vars(owner) else None
        if parameter is not None and parameter.default is not inspect.Parameter.empty:
            return parameter.default
    return getattr(cls, name)


def readme_summary(cls, text):
    """A task's ``summary`` / ``success_summary`` with each ``{keyword}`` or ``{keyword:unit}`` (UNITS)
    replaced by the keyword's default (``keyword_default``); a size of three equal values reads as one."""
    def replace(match):
        value, unit = keyword_default(cls, match.group(1)), match.group(2) or ""
        factor, suffix = UNITS[unit] if unit else (1.0, "")
        values = [float(v) for v in np.atleast_1d(value)]
        values = values[:1] if len(set(values)) == 1 else values
        return " x ".join(f"{factor * v:g}" for v in values) + suffix
    return re.sub(r"\{(\w+)(?::([^}]+))?\}", replace, text)


def code_list(names):
    return ", ".join(f"`{name}`" for name in names)


def readme_task_table():
    """The README's task table, from the task classes (``summary``, ``success_summary``,
    ``observation_types``, ``randomised_parameters``, ``episode_keywords``) and tissue_env.ENV_IDS."""
    import tissue_env

    rows = []
    for env_id, (entry_point, max_steps) in tissue_env.ENV_IDS.items():
        cls = getattr(tissue_env, entry_point.split(":")[1])
        rows.append([f"`{env_id}`", readme_summary(cls, cls.summary), readme_summary(cls, cls.success_summary),
                     f"{max_steps} steps", code_list(cls.observation_types()),
                     code_list(cls.randomised_parameters.values()) + "; episode draws: "
                     + code_list(cls.episode_keywords)])
    return table(["id", "task", "success", "episode", "observation types", "randomised per episode"], rows)


def readme_training_table():
    """The README's training table, from benchmarks/results/training.json: one row per entry (its
    env keywords, ``--variant``, in the setting column) and one for random / scripted per task and
    setting (none for a setting whose random and scripted results are its default's); the defaults'
    setting is left blank. Success rates
    as in the file, returns cut (not rounded) to two decimals."""
    def cut(value):
        return f"{int(value * 100) / 100:.2f}"

    def shown(setting):
        return "" if setting == "default" else setting

    rows = []
    entries = list(load("training.json").values())
    for env_id in dict.fromkeys(entry["env"] for entry in entries):
        task, settings = short_id(env_id).removesuffix("-v0"), {}
        for entry in (e for e in entries if e["env"] == env_id):
            setting = ", ".join(f"{k}={v}" for k, v in (entry.get("env_kwargs") or {}).items()) or "default"
            settings.setdefault(setting, entry)
            rows.append([task, entry["algo"].upper(), shown(setting), entry["timesteps"],
                         ", ".join(str(s) for s in entry["seeds"]), ", ".join(f"{s:g}" for s in entry["agent_success"]),
                         ", ".join(cut(r) for r in entry["agent_return"])])
        baselines = {setting: [f"{entry['random']['success_rate']:g} / {entry['scripted']['success_rate']:g}",
                               f"{cut(entry['random']['mean_return'])} / {cut(entry['scripted']['mean_return'])}"]
                     for setting, entry in settings.items()}
        rows += [[task, "random / scripted", shown(setting), "", "", *baseline] for setting, baseline in baselines.items()
                 if setting == "default" or baseline != baselines.get("default")]
    return table(["task", "policy", "setting", "env steps", "seeds", "success per seed", "return per seed"], rows)


#: README sections between ``<!-- generated: NAME -->`` and ``<!-- end generated: NAME -->``
README_TABLES = {"tasks": readme_task_table, "training": readme_training_table}


def readme():
    """README.md with its generated tables (README_TABLES) rewritten."""
    text = (ROOT / "README.md").read_text()
    for name, make in README_TABLES.items():
        begin = f"<!-- generated: {name} (docs/gen_pages.py; do not edit, run `python docs/gen_pages.py`) -->\n"
        end = f"<!-- end generated: {name} -->"
        if begin not in text or end not in text:
            raise LookupError(f"README.md has no generated {name} table (the markers {begin.strip()!r} ... {end!r})")
        head, rest = text.split(begin, 1)
        text = head + begin + make() + rest[rest.index(end):]
    return text
