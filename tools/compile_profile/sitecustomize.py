"""Where a test session's time goes: every XLA compilation, trace, lowering and compilation
cache hit of every Python process, with the test that caused it.

With this folder on PYTHONPATH and COMPILE_PROFILE_OUT naming a folder, each process that
imports JAX (pytest's workers and every subprocess they start, which inherit both
variables) appends one JSON line per event to OUT/<pid>.jsonl: the kind (compile, trace,
lower, hit), the seconds, the function's name and the test pytest was running
(PYTEST_CURRENT_TEST, which subprocesses inherit too). It hooks in when JAX's monitoring
module is imported, so a process that never imports JAX loads nothing more. Summarise with
`python tools/compile_profile/report.py OUT`:

    PYTHONPATH=tools/compile_profile COMPILE_PROFILE_OUT=/tmp/profile pytest
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import json
import os
import sys
from typing import Any

OUT = os.environ.get("COMPILE_PROFILE_OUT")
EVENTS = {
    "/jax/core/compile/backend_compile_duration": "compile",
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/compilation_cache/cache_retrieval_time_sec": "hit",
}


def _listen(monitoring: Any) -> None:
    """Append every event of EVENTS to this process's file."""
    path = os.path.join(OUT, f"{os.getpid()}.jsonl")
    command = " ".join(sys.argv[:3])[:100]

    def on_duration(event: str, duration: float, **details: Any) -> None:
        kind = EVENTS.get(event)
        if kind is None:
            return
        row = {
            "kind": kind,
            "seconds": round(duration, 4),
            "function": details.get("fun_name", ""),
            "test": os.environ.get("PYTEST_CURRENT_TEST", ""),
            "command": command,
        }
        with open(path, "a") as file:
            file.write(json.dumps(row) + "\n")

    monitoring.register_event_duration_secs_listener(on_duration)


class _AfterMonitoring(importlib.abc.MetaPathFinder):
    """Registers the listener once JAX's monitoring module has been executed."""

    name = "jax._src.monitoring"

    def find_spec(self, fullname: str, path: Any, target: Any = None) -> Any:
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        execute = spec.loader.exec_module

        def exec_module(module: Any) -> None:
            execute(module)
            _listen(module)

        spec.loader.exec_module = exec_module
        return spec


if OUT:
    os.makedirs(OUT, exist_ok=True)
    sys.meta_path.insert(0, _AfterMonitoring())
