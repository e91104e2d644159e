"""Session hooks: a selected test whose module defines ``start_in_background`` gets its slow,
self-contained work (test_numba_cache.py: processes compiling every kernel; test_training.py: its
training runs) started as soon as the tests are collected, beside the other tests; the module's
``stop_background`` ends what is still running when the session ends and cleans up."""

_started = []


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
