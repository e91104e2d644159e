"""The goal-conditioned API through ``gym.make``: the wrappers that ``gym.make`` puts around every
env forward ``compute_reward``.

A goal-conditioned env (``observation_type="goal"``) has ``compute_reward(achieved_goal,
desired_goal, info)``, and the goal-env checkers and hindsight replay call it on the env they are
given: stable-baselines3's ``check_env`` calls ``env.compute_reward`` on the object itself (it tells
a goal env by ``env.unwrapped``), its ``HerReplayBuffer`` calls it through ``VecEnv.env_method``,
which uses ``get_wrapper_attr``. Old gym's ``Wrapper`` forwarded the method; gymnasium's does not,
so ``gym.make(id, observation_type="goal")``, an env inside ``PassiveEnvChecker``, ``OrderEnforcing``
and ``TimeLimit``, failed ``check_env`` with "'TimeLimit' object has no attribute 'compute_reward'".

The other ways around it break a contract: a wrapper in the spec's ``additional_wrappers`` is
outermost under ``gym.make``, but ``gym.make_vec`` then refuses the task's ``vector_entry_point``
(gymnasium allows no additional wrappers with one), and a separate goal id would leave
``gym.make(id, observation_type="goal")`` failing. So ``forward_compute_reward`` gives those three
wrappers, and only them (they change neither the observation nor the reward), a ``compute_reward``
property that returns the wrapped env's: ``hasattr(wrapper, "compute_reward")`` is then exactly
``hasattr(wrapper.env, "compute_reward")``, False for every env without the method (any non-goal
env, of this package or another), so nothing else sees a difference. A class of gymnasium's that
already has a ``compute_reward`` is left as it is. Wrappers you add yourself do not forward it:
use ``env.get_wrapper_attr("compute_reward")`` or ``env.unwrapped.compute_reward`` there.
"""

from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit

#: The wrappers ``gym.make`` adds around an env (in this order, innermost first).
GYM_MAKE_WRAPPERS = (PassiveEnvChecker, OrderEnforcing, TimeLimit)


def _wrapped_compute_reward(self):
    # AttributeError (and so hasattr False) when the wrapped env has no compute_reward
    return self.env.compute_reward


#: The property added to each of GYM_MAKE_WRAPPERS.
COMPUTE_REWARD = property(_wrapped_compute_reward, doc=(
    "The wrapped env's ``compute_reward(achieved_goal, desired_goal, info)`` (a goal-conditioned env); "
    "AttributeError when it has none. Added by tissue_env.goal.forward_compute_reward."))


def forward_compute_reward(classes=GYM_MAKE_WRAPPERS) -> tuple:
    """Give each wrapper class of ``classes`` (default: ``gym.make``'s) without a ``compute_reward``
    the forwarding property; idempotent. Returns the classes that forward it through this property."""
    for cls in classes:
        if not hasattr(cls, "compute_reward"):
            cls.compute_reward = COMPUTE_REWARD
    return tuple(cls for cls in classes if getattr(cls, "compute_reward", None) is COMPUTE_REWARD)
