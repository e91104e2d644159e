"""Session hooks: the longest test files first (``LONGEST_FIRST``); a selected test whose module
defines ``start_in_background`` gets its slow, self-contained work (test_numba_cache.py: processes
compiling every kernel; test_training.py: its training runs) started as soon as the tests are
collected, beside the other tests (in a run on one process; a pytest-xdist worker runs it in the
test); the module's ``stop_background`` ends what is still running when the session ends."""

_started = []

#: The test files that take longest (seconds of a `pytest -n 2 --dist loadfile --durations=0` run,
#: summed per file: 175, 144, 122, 74, 57, 54, 46, 42, 40, 37, 33), run first. make test's two
#: pytest-xdist workers each take the next file as they free up; starting with the longest ends
#: them together (longest processing time first) instead of one worker finishing a long file alone.
LONGEST_FIRST = ("test_numba_cache.py", "test_env_vector.py", "test_resume.py", "test_training.py",
                 "test_env_visual.py", "test_trajectory_fixtures.py", "test_hyperelastic_dynamics.py",
                 "test_env_common.py", "test_env_palpation.py", "test_quasi_static.py", "test_validity.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: index for index, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FIRST)))  # stable: the rest keep their order


def pytest_collection_finish(session):
    if session.config.option.collectonly or hasattr(session.config, "workerinput"):
        return  # nothing to run; or a pytest-xdist worker, which collects the tests other workers run
    for item in session.items:  # every selected test: a module may start work for several of its tests
        module = getattr(item, "module", None)
        start = getattr(module, "start_in_background", None)
        if start is not None and start(item.name) and module not in _started:
            _started.append(module)


def pytest_sessionfinish(session):
    while _started:
        _started.pop().stop_background()
