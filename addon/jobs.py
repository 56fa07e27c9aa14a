"""Long Lowcam commands run beside Blender: the ``lowcam`` command line in a child process, polled by a timer.

Blender's main thread never waits on the engine. A :class:`Job` runs one or more ``lowcam`` commands one after
the other (``python -m lowcam.cli ...`` with the Python Blender runs and a ``PYTHONPATH`` on which the child finds
the engine where the add-on found it). Two reader threads keep the child's output lines (they touch no bpy); the
timer function :func:`tick` runs on the main thread: it starts the next command when one finishes, and calls the
job's ``done`` with the job when the last one has. A failed command ends the job with its one-line error
(``lowcam CMD: error: ...``); a cancelled job ends its child's whole process group. Either way the outputs the job
named and did not find before it started are removed (with the temporaries a killed command leaves), so a
cancelled job leaves no partial profile.

Headless (``blender -b`` or the bpy module) there is no event loop to run timers: :func:`wait` polls the job
from the caller instead (each poll returns at once), which is what the operators do there.

Contents
--------
- :data:`POLL_S`: how often the timer polls a running job (s)
- :data:`JOB_NICENESS`: how far below Blender a job's processes run (POSIX ``nice``; below normal on Windows)
- :data:`REDRAW_S`: the shortest time between two redraws of a running job's progress (s)
- :class:`Job`: one or more ``lowcam`` commands in a child process, their output, progress, result or error
- :func:`lowcam_command`: the command line that runs ``lowcam ARGS`` in a child process, and its environment
- :func:`group_running`: whether a process of a process group still runs (a zombie does not)
- :func:`current`: the job running now (one at a time), or None
- :func:`start`: start a job and the timer that polls it
- :func:`poll`: poll the current job once (never blocks); True while it runs
- :func:`tick`: the timer function: :func:`poll`, then redraw the panels and the status bar
- :func:`wait`: drive the current job to its end from the caller (headless scripts, tests)
- :func:`cancel`: stop the current job, its child processes and its partial outputs
- :func:`register`: cancel running jobs when Blender quits or loads another file
- :func:`unregister`: cancel the current job and remove the handlers
"""
from __future__ import annotations

import atexit
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

#: How often the timer polls a running job (s).
POLL_S = 0.1
#: How far below Blender a job's processes run (POSIX ``nice``; Windows: below normal priority), so that a diagnosis
#: using every core leaves Blender's own thread the CPU it needs to stay responsive.
JOB_NICENESS = 10


def lowcam_command(args) -> tuple[list[str], dict]:
    """``(argv, env)`` that run ``lowcam ARGS`` in a child process: ``sys.executable -m lowcam.cli`` (in Blender,
    Blender's own Python) with ``PYTHONPATH`` holding the folder the engine was imported from and this process's
    other import folders (the extension's wheels, Blender's modules), unbuffered output."""
    import lowcam

    engine_home = str(Path(lowcam.__file__).resolve().parent.parent)
    paths = [engine_home] + [p for p in sys.path if p and p != engine_home and os.path.isdir(p)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(dict.fromkeys(paths)), PYTHONUNBUFFERED="1")
    return [sys.executable, "-m", "lowcam.cli", *map(str, args)], env


def group_running(pgid: int) -> bool:
    """Whether a process of process group ``pgid`` still runs (POSIX). A member that has ended but waits to be
    reaped (a zombie: a grandchild orphaned when the child ended, reaped by init in its own time) does not run;
    where ``/proc`` lists no states, any member counts."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    if not os.path.isdir("/proc/self"):
        return True
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                with open(f"/proc/{entry.name}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()  # after the command name, which may hold spaces
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != b"Z":
                return True
    return False


class Job:
    """``steps`` ((label, lowcam arguments) pairs) run one after another in a child process.

    ``outputs``: files and folders the job writes; those that did not exist when it started are removed when it
    fails or is cancelled. ``done(job)`` runs on the main thread after the last step succeeded; ``failed(job)``
    after a failure (``job.error`` holds the one line). ``stdout`` holds every step's output lines."""

    def __init__(self, title: str, steps, outputs=(), done=None, failed=None):
        self.title = title
        self.steps = [(label, [str(a) for a in args]) for label, args in steps]
        self.outputs = [Path(p) for p in outputs]
        self.done, self.failed = done, failed
        self.step = -1
        self.process: subprocess.Popen | None = None
        self.stdout: list[str] = []
        self.stderr: list[str] = []          # the current step's
        self.error = ""
        self.state = "new"                   # new, running, finished, failed, cancelled
        self.started = self.step_started = 0.0
        self._fresh: list[Path] = []
        self._readers: list[threading.Thread] = []

    # -- the child process ---------------------------------------------------------------------------------
    def start(self) -> "Job":
        self._fresh = [p for p in self.outputs if not p.exists()]
        self.started = time.monotonic()
        self.state = "running"
        self._next()
        return self

    def _next(self) -> None:
        self.step += 1
        label, args = self.steps[self.step]
        argv, env = lowcam_command(args)
        self.stderr = []
        self.step_started = time.monotonic()
        own_group = {"start_new_session": True} if os.name == "posix" else \
            {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP | subprocess.BELOW_NORMAL_PRIORITY_CLASS}
        if os.name == "posix" and shutil.which("nice"):
            argv = ["nice", "-n", str(JOB_NICENESS), *argv]   # Blender's own thread keeps the CPU it needs
        self.process = subprocess.Popen(argv, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True, encoding="utf-8", errors="replace",
                                        bufsize=1, **own_group)
        self._readers = [threading.Thread(target=self._read, args=(stream, lines), daemon=True)
                         for stream, lines in ((self.process.stdout, self.stdout), (self.process.stderr, self.stderr))]
        for t in self._readers:
            t.start()

    @staticmethod
    def _read(stream, lines: list) -> None:
        """A reader thread: the stream's lines (carriage-return progress lines split too), never bpy."""
        for line in stream:
            for part in line.replace("\r", "\n").split("\n"):
                if part.strip():
                    lines.append(part.rstrip())
        stream.close()

    def poll(self) -> bool:
        """Advance the job without blocking; True while it runs."""
        if self.state != "running":
            return False
        rc = self.process.poll()
        if rc is None:
            return True
        for t in self._readers:
            t.join(timeout=1.0)              # the pipes close as the child exits: this is at once
        if rc != 0:
            self.error = self._error_line(rc)
            self._end("failed")
            return False
        if self.step + 1 < len(self.steps):
            self._next()
            return True
        self.state = "finished"
        return False

    def _error_line(self, rc: int) -> str:
        lines = [ln for ln in self.stderr if ln.strip()]
        errors = [ln for ln in lines if ": error: " in ln]
        if errors:
            return errors[-1].strip()
        if lines:
            return f"{self.steps[self.step][0]}: {lines[-1].strip()}"
        return f"{self.steps[self.step][0]}: the command ended with status {rc}"

    def cancel(self) -> None:
        """End the child and everything it started (its process group), then remove the partial outputs."""
        if self.state != "running":
            return
        p = self.process
        if p is not None and p.poll() is None:
            try:
                if os.name == "posix":
                    os.killpg(p.pid, signal.SIGTERM)
                else:               # Windows: the child's own children (an EXR read in a child) with it
                    subprocess.run(["taskkill", "/PID", str(p.pid), "/T", "/F"], capture_output=True, timeout=10)
                p.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):        # OSError: no such process, no taskkill
                if os.name == "posix":
                    try:
                        os.killpg(p.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                p.kill()
                p.wait()
            if os.name == "posix":  # a grandchild (a tool the child ran) may outlive it for a moment
                deadline = time.monotonic() + 2.0
                while group_running(p.pid) and time.monotonic() < deadline:
                    time.sleep(0.02)
                if group_running(p.pid):
                    try:
                        os.killpg(p.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
        self.error = "cancelled"
        self._end("cancelled")

    def _end(self, state: str) -> None:
        from lowcam.outputs import remove_stale_temporaries

        self.state = state
        for path in self._fresh:
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            elif path.exists():
                path.unlink(missing_ok=True)
        for folder in {p.parent for p in self.outputs if p.parent.is_dir()}:
            remove_stale_temporaries(folder)

    # -- what the panel shows ------------------------------------------------------------------------------
    @property
    def progress(self) -> str:
        """One line: the step, its last progress line and the seconds so far."""
        label = self.steps[max(self.step, 0)][0]
        count = f" ({self.step + 1}/{len(self.steps)})" if len(self.steps) > 1 else ""
        last = self.stderr[-1].strip() if self.stderr else ""
        return f"{label}{count}: {last + ', ' if last else ''}{time.monotonic() - self.started:.0f} s"


_current: Job | None = None


def current() -> Job | None:
    """The job running now, or None."""
    return _current if _current is not None and _current.state == "running" else None


def start(job: Job) -> Job:
    """Start ``job`` (one job runs at a time: a running one is refused) and register the timer that polls it."""
    global _current
    from lowcam.errors import LowcamError

    if current() is not None:
        raise LowcamError(f"{_current.title} is running; wait for it or cancel it first")
    _current = job.start()
    if not bpy.app.timers.is_registered(tick):
        bpy.app.timers.register(tick, first_interval=POLL_S)
    return job


def _finish(job: Job) -> None:
    """Hand a finished or failed job's outcome to its owner, on the main thread."""
    callback = job.done if job.state == "finished" else job.failed
    if callback is not None:
        callback(job)


def poll() -> bool:
    """Poll the current job once (returns at once); when it ends, run its ``done`` or ``failed``. True while it
    runs."""
    job = _current
    if job is None or job.state != "running":
        return False
    if job.poll():
        return True
    _finish(job)
    return False


#: The shortest time between two redraws for a running job's changing progress line (s): each one redraws the
#: panels, which a software-drawn window (no GPU) pays for in tenths of a second on a busy machine.
REDRAW_S = 0.5
_shown: list = [None, 0.0]       # the progress line on show and when it was drawn (time.monotonic(), s)


def _redraw(text: str | None) -> None:
    """The panels and the status bar show ``text`` (None clears the status bar); nothing when it is on show, or when
    a job's line changed within :data:`REDRAW_S` of the last redraw (the job's start and end redraw at once)."""
    now = time.monotonic()
    if text == _shown[0] or (None not in (text, _shown[0]) and now - _shown[1] < REDRAW_S):
        return
    _shown[:] = text, now
    wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        workspace = getattr(window, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(text)
        for area in window.screen.areas:
            if area.type in ("PROPERTIES", "NODE_EDITOR", "IMAGE_EDITOR"):
                area.tag_redraw()


def tick():
    """The timer function (main thread): poll the job, redraw; the next call in :data:`POLL_S`, none at the end."""
    running = poll()
    try:
        _redraw(_current.progress if running and _current is not None else None)
    except (AttributeError, ReferenceError, RuntimeError):
        pass                                                # no window (headless), or a window closing
    return POLL_S if running else None


def wait(timeout_s: float | None = None) -> Job | None:
    """Drive the current job to its end from the caller, polling every :data:`POLL_S` (headless Blender and the
    bpy module run no timers); after ``timeout_s`` it is cancelled. Returns the job."""
    job = _current
    t0 = time.monotonic()
    while poll():
        if timeout_s is not None and time.monotonic() - t0 > timeout_s:
            cancel()
            break
        time.sleep(POLL_S)
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    return job


def cancel() -> Job | None:
    """Stop the current job: its child processes end and its partial outputs are removed; ``failed`` runs."""
    job = current()
    if job is not None:
        job.cancel()
        _finish(job)
    return job


@persistent
def _cancel_on_load(*args):
    cancel()


def register():
    if _cancel_on_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_cancel_on_load)
    atexit.register(cancel)


def unregister():
    cancel()
    while _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
    atexit.unregister(cancel)
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
