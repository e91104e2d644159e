"""Session hooks: a selected test whose module defines ``start_in_background`` gets its slow,
self-contained work (test_numba_cache.py: processes compiling every kernel) started as soon as the
tests are collected, beside the other tests; ``stop_background`` ends it if the session ends first."""

_started = []


def pytest_collection_finish(session):
    if session.config.option.collectonly or hasattr(session.config, "workerinput"):
        return  # nothing to run; or a pytest-xdist worker, which collects the tests other workers run
    for item in session.items:
        module = getattr(item, "module", None)
        start = getattr(module, "start_in_background", None)
        if start is not None and module not in _started and start(item.name):
            _started.append(module)


def pytest_sessionfinish(session):
    while _started:
        _started.pop().stop_background()
