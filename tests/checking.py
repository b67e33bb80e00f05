"""What the language's tests check of a schedule: `smol-dsl check`'s verdict on its text, and
that one that passes is finite and positive in float32 wherever it is evaluated."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.cli import main

if TYPE_CHECKING:
    from pathlib import Path

    import pytest

    import smol_dsl

DENSE = np.linspace(0.0, 1.0, 20_001, dtype=np.float32)


def check_cli(directory: Path, text: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """`smol-dsl check hostile.sched` on `text`, in-process: its exit status and stderr, which
    never holds a traceback or an internal error."""
    path = directory / "hostile.sched"
    path.write_text(text, encoding="utf-8")
    code = main(["check", str(path)])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return code, err


def assert_finite_everywhere(schedule: smol_dsl.Schedule, phase_counts: list[int]) -> None:
    """alpha is finite and positive on a dense grid of t and at every phase of each count."""
    alpha = np.asarray(schedule.alpha(jnp.asarray(DENSE)))
    assert np.isfinite(alpha).all() and (alpha > 0).all(), alpha[~(np.isfinite(alpha) & (alpha > 0))][:5]
    for n in phase_counts:
        phases = np.asarray(schedule.phase_alphas(n, jax.random.key(n)))
        assert phases.shape == (n,)
        assert np.isfinite(phases).all() and (phases > 0).all(), (n, phases)
        schedule.checked_phase_alphas(n, jax.random.key(n))
