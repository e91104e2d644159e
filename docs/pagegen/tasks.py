"""docs/tasks/<task>.md: one page per task, from the task class docstring and tissue_env.ENV_IDS."""

from __future__ import annotations

import inspect
import re

from .common import HEADER, table


def rst_to_markdown(text):
    """The docstrings' ``literal`` (reStructuredText) becomes `literal` (Markdown)."""
    return re.sub(r"``(.+?)``", r"`\1`", text)


def task_page(env_id):
    import tissue_env

    entry_point, max_steps = tissue_env.ENV_IDS[env_id]
    module_name, class_name = entry_point.split(":")
    cls = getattr(tissue_env, class_name)
    vector = tissue_env.VECTOR_ENTRY_POINTS.get(env_id, "")
    title = class_name.removesuffix("Env")
    doc = rst_to_markdown(inspect.getdoc(cls))
    facts = table(["", ""], [
        ["registered id", f"`{env_id}`"],
        ["class", f"`{module_name}.{class_name}`"],
        ["vector env", f"`{vector.replace(':', '.')}`" if vector else "-"],
        ["episode length", f"{max_steps} env steps (`max_episode_steps`)"],
    ])
    return (HEADER.format(source=f"the docstring of {module_name}.{class_name} and tissue_env.ENV_IDS")
            + f"# {title}\n\n" + facts + "\n"
            + f"```python\nimport gymnasium as gym\nimport tissue_env\n\nenv = gym.make(\"{env_id}\")\n```\n\n"
            + doc.rstrip() + "\n")
