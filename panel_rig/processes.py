"""Stopping processes cleanly: the child processes of the one-command sessions (demo, control demo, live flutter
test), and our own ROS programs (node, controller, operator) on SIGINT / SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: exit statuses as a shell reports a program ended by a signal (128 + the signal's number), one home for every
#: program of the package: Ctrl-C (SIGINT), SIGTERM, and a reader that left the pipe (SIGPIPE)
INTERRUPTED_STATUS = 128 + signal.SIGINT
TERMINATED_STATUS = 128 + signal.SIGTERM
BROKEN_PIPE_STATUS = 128 + signal.SIGPIPE
#: wall seconds a session's client waits for the rig node to come up: a node's first start on an install compiles the
#: numba kernels (23-36 s measured on this 2-core machine, more under load; a warm start ~2 s). Silence timeouts count only
#: once the rig is up (a fresh clone's first `make run` failed when its operator's 30 s ran out at 28 s)
RIG_STARTUP_TIMEOUT_S = 180.0




#: set by :func:`spawn` in its child's environment: the parent's process id, for :func:`follow_parent`
PARENT_ENV = "PANEL_RIG_PARENT_PID"


def spawn(cmd: list[str], env: dict[str, str] | None = None, **kwargs: object) -> subprocess.Popen:
    """A child program of a one-command session (node, operator, controller) in its own session: a Ctrl-C in the
    terminal reaches the session's own program only, which then stops its children in order (wind off first,
    then the node, whose bag it closes). Should the parent die without stopping them (SIGKILL), the child stops
    too (:func:`follow_parent`, called by the child itself: no code runs between fork and exec)."""
    env = dict(os.environ if env is None else env, **{PARENT_ENV: str(os.getpid())})
    return subprocess.Popen(cmd, start_new_session=True, env=env, **kwargs)


def follow_parent() -> None:
    """In a child started by :func:`spawn`: SIGTERM when the parent dies (Linux's PR_SET_PDEATHSIG), or now if it
    already has; the program's SIGTERM handling then stops it cleanly. Nothing without the parent's mark."""
    parent = os.environ.pop(PARENT_ENV, None)  # not inherited further
    if parent is None:
        return
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return  # not Linux: the parent's own stop handling remains
    if os.getppid() != int(parent):  # the parent died before the request was in place
        os.kill(os.getpid(), signal.SIGTERM)


@contextmanager
def sigterm_exits() -> Iterator[None]:
    """Within the block SIGTERM raises SystemExit(143): a ``kill`` or a ``timeout`` leaves through the program's
    clean-up (``finally`` blocks stop its children) as Ctrl-C does; without it the program ended at once and its
    node went on recording. The previous handler comes back on leaving the block."""

    def terminated(signum: int, frame: object) -> None:
        raise SystemExit(TERMINATED_STATUS)

    previous = signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Within the block SIGINT and SIGTERM wait; on leaving it the first one that came is raised again, through the
    handler that stood before (Ctrl-C's KeyboardInterrupt, :func:`sigterm_exits`' SystemExit, ...). For work that
    must not be cut in the middle: a block of readings handed to the recording (a Ctrl-C inside the bag writer left
    a summary counting a message its data section did not hold). Outside the main thread, where no handler can be
    set, the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []

    def hold(signum: int, frame: object) -> None:
        pending.append(signum)

    previous = {signum: signal.signal(signum, hold) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if pending:
            signal.raise_signal(pending[0])


def interruption(exc: BaseException) -> signal.Signals | None:
    """The signal an exception stands for: SIGINT for KeyboardInterrupt (Ctrl-C), SIGTERM for the SystemExit of
    :func:`sigterm_exits`; None for any other."""
    if isinstance(exc, KeyboardInterrupt):
        return signal.SIGINT
    if isinstance(exc, SystemExit) and exc.code == TERMINATED_STATUS:
        return signal.SIGTERM
    return None


class StoppedRun(BaseException):
    """A run that stopped before its end with what it measured so far (``payload``, to report as a stopped run's), a
    line saying why (``message``) and the program's exit status (``exit_status``). The two kinds below differ in
    what ``except`` takes them: :class:`Interrupted` (a signal) and :class:`Aborted` (a failure)."""

    def __init__(self, payload: dict, message: str) -> None:
        super().__init__(message)
        self.payload, self.message = payload, message

    @property
    def exit_status(self) -> int:
        """The program's exit status for this stop."""
        raise NotImplementedError


class Interrupted(StoppedRun):
    """A run stopped by a signal. A BaseException, as KeyboardInterrupt: no ``except Exception`` on the way takes it
    for an error."""

    def __init__(self, signum: signal.Signals, payload: dict, message: str) -> None:
        super().__init__(payload, message)
        self.signum = signum

    @property
    def exit_status(self) -> int:
        """The shell's status for the signal (130 Ctrl-C, 143 SIGTERM)."""
        return 128 + int(self.signum)


class Aborted(StoppedRun, RuntimeError):
    """A run stopped by a failure it cannot go on through (its recording failed, its rig node was lost). A
    RuntimeError too: a caller that does not report the payload still prints the line (exit 1)."""

    @property
    def exit_status(self) -> int:
        """1: the run failed."""
        return 1


def module_command(module: str, *args: str) -> list[str]:
    """``python -P -m module args``: a child program of this install. ``-P`` keeps the working directory off
    sys.path, so a ``panel_rig/`` directory where the user stands (another checkout) is never what the child runs
    while this process runs the installed one."""
    return [sys.executable, "-P", "-m", module, *args]


class StopRequest(threading.Event):
    """The stop flag of a ROS program, set by :func:`signals_set`; ``signum`` says which signal set it."""

    signum: int | None = None

    @property
    def exit_status(self) -> int:
        """The shell's status for the signal (130 Ctrl-C, 143 SIGTERM)."""
        return 128 + (self.signum if self.signum is not None else signal.SIGINT)


def stop_exception(stop: StopRequest) -> BaseException:
    """What a stop request stands for, to raise between rclpy calls: KeyboardInterrupt (Ctrl-C), or for SIGTERM
    the SystemExit of :func:`sigterm_exits` (:func:`interruption` maps both back to their signal)."""
    return SystemExit(TERMINATED_STATUS) if stop.signum == signal.SIGTERM else KeyboardInterrupt()


@contextmanager
def signals_set(stop: threading.Event, restore_when_stopped: bool = True) -> Iterator[None]:
    """Within the block SIGINT and SIGTERM only set ``stop``: the spin loop turns it into a clean exit between
    rclpy calls. (rclpy's own handler shuts the context down under whatever call is running, and Python's raises
    KeyboardInterrupt wherever it lands: inside rclpy's conversion of a taken sample it left the subscription's
    callback group busy for good.) The previous handlers come back on leaving the block, unless
    ``restore_when_stopped`` is false and ``stop`` is set then: a program that was stopped is on its way out, and
    ignores both signals from there on (a node that had closed its bag ended 130 or 143, killed by the Ctrl-C or
    SIGTERM an impatient operator sent again, in the moments between its ROS session and its exit; an ignored
    signal is the one disposition the interpreter's finalisation leaves in place, it resets Python handlers)."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum: int, _frame: object) -> None:
        if isinstance(stop, StopRequest) and stop.signum is None:
            stop.signum = signum
        stop.set()

    for s in previous:
        signal.signal(s, handler)
    try:
        yield
    finally:
        stopping = stop.is_set() and not restore_when_stopped
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_IGN if stopping else handler)


def stop(proc: subprocess.Popen, timeout_s: float) -> int:
    """SIGINT (a node closes its bag and exits 0), wait up to ``timeout_s`` (wall); SIGKILL only if it does not
    stop. Returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
