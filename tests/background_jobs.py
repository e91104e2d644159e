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
