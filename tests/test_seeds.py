"""Seeds: exactly the ones that give distinct random streams (0 .. 2**32 - 1) are taken, by the
library and the command line; any other is refused before anything is created."""

from __future__ import annotations

import numpy as np
import pytest
from small_runs import CONFIG, FLAGS, RUN, cli

from smol_dsl.errors import UserInputError
from smol_dsl.runner import preset_config, schedule_key
from smol_dsl.runner.sweep import plan_sweep
from smol_dsl.seeds import SEED_MAX, SeedError, check_seed


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([*RUN, "--seed", "4294967296"], "--seed 4294967296: seeds are whole numbers from 0 to 4294967295"),
        ([*RUN, "--seed", "-1"], "--seed -1: seeds are whole numbers from 0 to 4294967295"),
        ([*RUN, "--seed", "99999999999999999999"], "--seed 99999999999999999999: seeds are whole numbers"),
        (["sweep", "walker2d", "human", *FLAGS, "--first-seed", "-3"], "--first-seed -3: seeds are whole numbers"),
        (
            ["sweep", "walker2d", "human", *FLAGS, "--first-seed", "4294967295", "--seeds", "2"],
            "--first-seed 4294967295 with --seeds 2: the seeds would run up to 4294967296",
        ),
    ],
)
def test_seeds_outside_the_distinct_range_are_refused(argv, message, tmp_path, capsys):
    code, err = cli([*argv, "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and message in err
    assert not (tmp_path / "out").exists()


def test_the_seed_range_is_exactly_the_distinct_streams(library):
    assert check_seed(0) == 0 and check_seed(np.uint32(SEED_MAX), "--seed") == SEED_MAX
    for bad in (SEED_MAX + 1, -1, 2**70, 1.5, "3", True):
        with pytest.raises(SeedError):
            check_seed(bad)
    assert issubclass(SeedError, UserInputError) and issubclass(SeedError, ValueError)
    assert preset_config("walker2d", seed=SEED_MAX).seed == SEED_MAX
    with pytest.raises(SeedError, match="seed 4294967296"):
        preset_config("walker2d", seed=2**32)
    with pytest.raises(SeedError, match="seed -1"):
        plan_sweep([library["human"]], [0, -1], CONFIG)
    # the aliasing being refused: JAX keeps 32 bits, so these are the same stream
    np.testing.assert_array_equal(
        np.asarray(library["random"].phase_alphas(10, schedule_key(2**32))),
        np.asarray(library["random"].phase_alphas(10, schedule_key(0))),
    )
    assert not np.array_equal(
        np.asarray(library["random"].phase_alphas(10, schedule_key(SEED_MAX))),
        np.asarray(library["random"].phase_alphas(10, schedule_key(0))),
    )
