"""docs/generated/training.md: trained agents against random and scripted policies, difficulty
levels, learning curves and throughput, from training*.json, difficulty.json and
rllib_throughput*.json."""

from __future__ import annotations

from .common import DOCS, HEADER, RESULTS, caption, command_for, figure, load, num, pct, runnable, short_id, table


def training_page():
    out = [HEADER.format(source="benchmarks/results/training.json, training_batched.json, training_pixels.json, "
                                "training_speed.json and rllib_throughput*.json"),
           "# Training\n\n",
           "stable-baselines3 agents on every task, against a random policy and the task's scripted "
           "controller (`env.unwrapped.scripted_action()`), each evaluated over the episodes given. "
           "Train one yourself with `python -m training.train` (see [getting started](../getting-started.md)). "
           "The env keywords column gives the environment keywords of a row's runs (`--variant` of "
           "`training.benchmark`: `observation_type=goal` is SAC with stable-baselines3's `HerReplayBuffer` "
           "on the goal observation, `difficulty=hard` the task's hard setting).\n\n"]
    for name, title in (("training.json", "One env per agent"), ("training_batched.json", "Batched vector env")):
        data = load(name)
        out += [f"## {title}\n\n"]
        rows = []
        commands = []
        for entry in data.values():
            success = entry["agent_success"]
            setting = ", ".join(f"{key}={value}" for key, value in (entry.get("env_kwargs") or {}).items())
            rows.append([short_id(entry["env"]), entry["algo"], setting or "default", entry["vec_env"], entry["timesteps"],
                         " ".join(str(seed) for seed in entry["seeds"]),
                         ", ".join(pct(s, 3) for s in success), pct(sum(success) / len(success)),
                         pct(entry["random"]["success_rate"]), pct(entry["scripted"]["success_rate"]),
                         num(entry["train_wall_clock_s"])])
            commands.append(entry["command"])
        out += [f"*Regenerate `benchmarks/results/{name}`, one command per row:*\n\n"]
        out += ["```\n" + "\n".join(commands) + "\n```\n\n"]
        out += [table(["env", "algo", "env keywords", "vec env", "timesteps", "seeds", "agent success per seed (%)", "mean (%)",
                       "random (%)", "scripted (%)", "train wall s (per seed)"], rows), "\n"]
    out += pixels_section()
    if (RESULTS / "difficulty.json").is_file():
        difficulty = load("difficulty.json")
        out += ["## Difficulty levels\n\n",
                "Each task's `difficulty` keyword (`\"easy\"`, `\"default\"`, `\"hard\"`) sets the keywords of its "
                "`DIFFICULTY` table (see the task pages). Per level, the scripted controller and random actions on the "
                "same seeds: success (the last step's `is_success`, which at a level without termination at a success "
                "is a success held to the episode's end), episodes that reached a success at some step, the mean steps "
                "to the first success of those, the mean return and the largest spring strain met.\n\n",
                caption(difficulty["command"], "difficulty.json"), "\n"]
        rows = []
        for row in difficulty["results"]:
            keywords = ", ".join(f"{key}={value}" for key, value in row["keywords"].items())
            for policy in ("scripted", "random"):
                result = row[policy]
                rows.append([short_id(row["env_id"]), row["difficulty"], keywords if policy == "scripted" else "",
                             policy, row["seeds"], pct(result["success_rate"]), pct(result["reached_rate"]),
                             num(result["mean_steps_to_success"]), num(result["mean_return"]),
                             num(result.get("mean_start_distance_m") and 1000 * result["mean_start_distance_m"]),
                             num(result["max_strain"])])
        out += [table(["env", "difficulty", "keywords", "policy", "episodes", "success (%)", "reached (%)",
                       "steps to success", "return", "start distance (mm)", "max strain"], rows), "\n"]
    figures = sorted(p.name for p in (DOCS / "figures").glob("learning_*.png"))
    out += ["## Learning curves\n\n"] + [figure(name, name[len("learning_"):-len(".png")].replace("_", " ")) + "\n"
                                          for name in figures]

    speed = load("training_speed.json")
    modes = list(speed["results"][0]["steps_per_s"])
    out += ["## Training throughput\n\n", f"Unit: {speed['unit']}.\n\n",
            caption(command_for("training_speed.py"), "training_speed.json"), "\n",
            table(["env", "envs", "timesteps"] + [f"{m} steps/s" for m in modes],
                  [[short_id(r["env_id"]), r["n_envs"], r["timesteps"]] + [num(r["steps_per_s"][m]) for m in modes]
                   for r in speed["results"]]), "\n"]

    out += ["## RLlib throughput\n\nSee [RLlib](../rllib.md) for the setup and a cluster run.\n\n"]
    for name in sorted(p.name for p in RESULTS.glob("rllib_throughput*.json")):
        data = load(name)
        if name == "rllib_throughput.json":
            command = command_for("rllib_throughput.py")
        else:  # a variant run: its arguments are read back from the file's own records
            envs = sorted({r["env"] for r in data["results"]})
            runners = sorted({r["num_env_runners"] for r in data["results"]})
            per_runner = sorted({r["num_envs_per_env_runner"] for r in data["results"]})
            command = (f"python -m benchmarks.rllib_throughput --envs {' '.join(envs)} --runners "
                       f"{' '.join(map(str, runners))} --envs-per-runner {' '.join(map(str, per_runner))} "
                       f"--out benchmarks/results/{name}")
        out += [f"Ray {data['ray_version']}, {data['cpu_count']} CPUs; {data['note']}.\n\n", caption(command, name), "\n",
                table(["env", "runners", "envs per runner", "train steps/s", "sample steps/s",
                       "sample steps per runner CPU s", "plain env steps/s"],
                      [[short_id(r["env"]), r["num_env_runners"], r["num_envs_per_env_runner"],
                        num(r["train_env_steps_per_s"]), num(r["sample_env_steps_per_s"]),
                        num(r["sample_env_steps_per_runner_cpu_s"]), num(r["plain_env_steps_per_s"])]
                       for r in data["results"]]), "\n"]
    return "".join(out)


def pixels_section():
    """Agents trained from camera images alone (training_pixels.json)."""
    data = load("training_pixels.json")
    out = ["## From pixels\n\n",
           "PPO with SB3's CnnPolicy on the camera image alone (`observation_type=\"rgb\"`, 64 x 64 px; "
           "hyperparameters `training/hyperparams/ppo_pixels.yml`), against random actions and the scripted "
           "controller on the same episode seeds. *Regenerate `benchmarks/results/training_pixels.json`, one "
           "command per row (each runs the training and evaluation commands below it):*\n\n"]
    out += ["```\n" + "\n".join(line for entry in data.values()
                                 for line in (runnable(entry["command"]), "  " + entry["train_command"],
                                              "  " + entry["evaluate_command"])) + "\n```\n\n"]
    out += [table(["env", "algo", "observation", "timesteps", "seeds", "agent success per seed (%)",
                   "agent return per seed", "random success (%) / return", "scripted success (%) / return",
                   "beats random", "train wall s per seed"],
                  [[short_id(e["env"]), e["algo"], f"{e['env_kwargs']['observation_type']} "
                    f"{e['env_kwargs']['image_size']} px", e["timesteps"], " ".join(map(str, e["seeds"])),
                    ", ".join(pct(s) for s in e["agent_success"]), ", ".join(num(r) for r in e["agent_return"]),
                    f"{pct(e['random']['success_rate'])} / {num(e['random']['mean_return'])}",
                    f"{pct(e['scripted']['success_rate'])} / {num(e['scripted']['mean_return'])}",
                    ", ".join(str(b) for b in e["beats_random"]), ", ".join(num(w) for w in e["train_wall_clock_s"])]
                   for e in data.values()]), "\n"]
    return out
