"""The prover's time budgets: a method that runs out of CPU time is stopped, always."""

from __future__ import annotations

import gc
import signal
import sys
import time

import pytest

from smol_dsl.language.prover import VerificationTimeoutError, time_limit

UNSTOPPED = 30.0
"""CPU seconds the code under a limit would burn if nothing stopped it; a limit of 0.1 s
must stop it long before (STOPPED): the margin is for a busy process, whose other threads
and garbage collector also spend its CPU time."""
STOPPED = 10.0


def spin(seconds: float) -> None:
    """Burn `seconds` of this process's CPU time."""
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_a_time_limit_stops_the_code_under_it():
    started = time.process_time()
    with pytest.raises(VerificationTimeoutError), time_limit(0.1):
        spin(UNSTOPPED)
    assert time.process_time() - started < STOPPED


def test_an_alarm_lost_in_a_gc_callback_fires_again(monkeypatch):
    """Python hands an exception raised in a gc callback to sys.unraisablehook and goes on;
    a hook of the test's own records them (pytest's would format a traceback, reading
    files, while the alarm still fires)."""

    def slow_callback(phase: str, info: dict) -> None:
        if phase == "start":
            spin(0.3)  # the alarm fires in here, and Python ignores a gc callback's exception

    lost: list[type[BaseException]] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda unraisable: lost.append(unraisable.exc_type))
    handler = signal.getsignal(signal.SIGPROF)
    gc.callbacks.append(slow_callback)
    try:
        started = time.process_time()
        with pytest.raises(VerificationTimeoutError), time_limit(0.1):
            gc.collect()
            spin(UNSTOPPED)
    finally:
        gc.callbacks.remove(slow_callback)
    assert VerificationTimeoutError in lost  # the first alarms were lost in the callback
    assert time.process_time() - started < STOPPED
    spin(0.2)  # no alarm is left once the limit is over
    assert signal.getsignal(signal.SIGPROF) is handler
    assert signal.getitimer(signal.ITIMER_PROF) == (0.0, 0.0)
