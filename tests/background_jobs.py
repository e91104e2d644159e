"""Self-contained slow work of a test module, run on a thread of its own beside the other tests.

A module defines its jobs (functions of a ``Jobs`` and a folder of their own) and starts the ones
its selected tests read from ``start_in_background`` (tests/conftest.py calls it when the session
starts); a test waits for its job's result (``Jobs.result``), and a job's exception is raised there.
The processes a job starts are handed to ``Jobs.adopt``: run at a lower priority if asked, and
killed with their session by ``Jobs.close`` when the session ends before the job does."""

import os
import signal
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


class Jobs:
    def __init__(self, jobs: dict, prefix: str, niceness: int = 0):
        """``jobs``: name -> function(jobs, folder); they run one after the other, in the order they are
        submitted, each in a folder of its own under a temporary folder removed by ``close``; the
        processes adopted are run ``niceness`` below this process's priority."""
        self.functions = jobs
        self.niceness = niceness
        self.folder = tempfile.TemporaryDirectory(prefix=prefix)
        self.path = Path(self.folder.name)
        self.executor = ThreadPoolExecutor(1, thread_name_prefix=prefix)
        self.futures = {}
        self.processes = []
        self.lock = threading.Lock()
        self.closed = False

    def submit(self, name):
        if name not in self.futures:
            folder = self.path / name
            folder.mkdir()
            self.futures[name] = self.executor.submit(self.functions[name], self, folder)
        return self.futures[name]

    def result(self, name):
        return self.submit(name).result()

    def adopt(self, process):
        """A process a job started, with ``start_new_session=True`` (``close`` kills its session)."""
        with self.lock:
            self.processes.append(process)
            if self.closed:
                os.killpg(process.pid, signal.SIGKILL)
                return
        if self.niceness:
            try:  # at once, before the process starts processes of its own (a vec env's workers)
                os.setpriority(os.PRIO_PROCESS, process.pid,
                               min(os.getpriority(os.PRIO_PROCESS, 0) + self.niceness, 19))
            except OSError:
                pass

    def close(self):
        with self.lock:
            self.closed = True
            for process in self.processes:
                if process.poll() is None:
                    os.killpg(process.pid, signal.SIGKILL)  # its session: the process and its children
        for future in self.futures.values():
            future.cancel()
        self.executor.shutdown(wait=True)
        self.folder.cleanup()


class ModuleJobs:
    """A test module's background jobs, as tests/conftest.py drives them: the module binds
    ``start_in_background = module_jobs.start`` and ``stop_background = module_jobs.stop``, and its
    ``jobs`` fixture yields from ``module_jobs.fixture()``. ``tests_of_jobs``: test name -> the job it
    reads; the other arguments are ``Jobs``'."""

    def __init__(self, jobs: dict, prefix: str, tests_of_jobs: dict, niceness: int = 0):
        self.jobs, self.prefix, self.tests_of_jobs, self.niceness = jobs, prefix, tests_of_jobs, niceness
        #: the jobs started by ``start`` (tests/conftest.py), or None
        self.background = None

    def start(self, name):
        """tests/conftest.py, after collection, for each selected test of the module: start the job the
        test ``name`` reads, if it reads one; whether it did."""
        if name not in self.tests_of_jobs:
            return False
        if self.background is None:
            self.background = Jobs(self.jobs, self.prefix, niceness=self.niceness)
        self.background.submit(self.tests_of_jobs[name])
        return True

    def stop(self):
        """The session ended: end the jobs still running and remove their folder."""
        if self.background is not None:
            self.background.close()
            self.background = None

    def fixture(self):
        """The jobs ``start`` started; or (a pytest-xdist worker) jobs of the module's own, run when a
        test asks for them."""
        if self.background is not None:
            yield self.background
            return
        own = Jobs(self.jobs, self.prefix, niceness=self.niceness)
        yield own
        own.close()
