"""Fuzzing: arbitrary text and bytes, and mutations of the bundled schedules (and examples/),
multi-channel ones included.

Whatever the input, `smol_dsl.parse` / `smol_dsl.load` either return a `Schedule` or raise a
`ScheduleError` that names the file, the line and column (where it has a place) and ends with a
hint; `smol-dsl check` exits with 0 or 2 and never prints a traceback; and no text ever reaches
Python's `eval`.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from budget import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from strategies import multi_channel_schedules

import smol_dsl
from smol_dsl.language.library import library_dir

REPO = Path(__file__).resolve().parent.parent
LIBRARY_FILES = sorted(library_dir().glob("*.sched")) + sorted((REPO / "examples").glob("*.sched"))
LIBRARY = {path.name: path.read_text(encoding="utf-8") for path in LIBRARY_FILES}

COMMON = dict(
    deadline=None,
    report_multiple_bugs=False,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# ----------------------------------------------------------------------------- inputs

KEYWORDS = (
    "name description let bounds extinction continuous constant linear bell at width random every expr tail "
    "increasing decreasing exp log sqrt sin cos tanh abs min max pi e t u channel final gear mass friction gravity"
).split()
TOKENS = (
    *KEYWORDS,
    *"0 1 2 0.5 1.5 .5 90 100 1e3 1e-3 2.5E+1 1e400 1e-400 1e99999 10**10**10 0.0".split(),
    *"% %% .. : -> = , ( ) + - * / ** # \" ' ^ [ ] . ...".split(),
    "90%",
    "10%",
    "0%",
    "100%",
    "0% .. 90%:",
    "90% .. 100%: tail",
    "channel mass\n",
    "channel gear[left_leg]\n",
    "channel gravity[a]",
    "channel gear[a, a]",
    "final 0.5\n",
    "left_leg",
    '"SMOL"',
    " ",
    "  ",
    "\t",
    "\n",
    "\r\n",
    "\r",
    "\ufeff",
    "\x00",
    "\x0c",
    "\u2028",
    "é",
    "→",
    "α",
    "nan",
    "inf",
    "__import__",
)
SEPARATORS = st.sampled_from(("", " ", " ", "\n", "  ", "\t"))

language_text = st.text(
    alphabet=st.sampled_from(sorted(set("".join(TOKENS)) | set("0123456789%.:->=,()+-*/#\n "))), max_size=300
)
token_soup = st.lists(st.tuples(st.sampled_from(TOKENS), SEPARATORS), max_size=40).map(
    lambda pairs: "".join(token + sep for token, sep in pairs)
)
any_text = st.text(max_size=300)
fragments = st.sampled_from(TOKENS) | st.text(max_size=3)
numbers = st.sampled_from(("0", "-1", "1e400", "1e-400", "99999", "1/0", "0.0000001", "2 ** 2000", "-0.5", ".5"))

TOKEN = re.compile(r"\d+(?:\.\d+)?(?:[eE][+-]?\d+)?|[A-Za-z_]\w*|\.\.|->|\*\*|\S")


@st.composite
def mutation(draw, text: str) -> str:
    """One random edit: delete, insert, replace a character or a token, or move lines."""
    op = draw(
        st.sampled_from(
            (
                "delete",
                "insert",
                "replace char",
                "replace token",
                "replace number",
                "swap lines",
                "duplicate line",
                "delete line",
                "truncate",
            )
        )
    )
    lines = text.split("\n")
    if op in ("swap lines", "duplicate line", "delete line"):
        i = draw(st.integers(0, len(lines) - 1))
        j = draw(st.integers(0, len(lines) - 1))
        if op == "swap lines":
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "duplicate line":
            lines.insert(j, lines[i])
        else:
            del lines[i]
        return "\n".join(lines)
    if op in ("replace token", "replace number"):
        tokens = [m for m in TOKEN.finditer(text) if op == "replace token" or m.group()[0].isdigit()]
        if not tokens:
            return text
        m = draw(st.sampled_from(tokens))
        new = draw(fragments if op == "replace token" else numbers)
        return text[: m.start()] + new + text[m.end() :]
    i = draw(st.integers(0, len(text)))
    if op == "delete":
        return text[:i] + text[i + draw(st.integers(1, 12)) :]
    if op == "insert":
        return text[:i] + draw(fragments) + text[i:]
    if op == "replace char":
        return text[:i] + draw(st.characters()) + text[i + 1 :]
    return text[:i]  # truncate


@st.composite
def mutated_library(draw) -> tuple[str, str]:
    """(name, text): a bundled schedule with one to four random edits."""
    name = draw(st.sampled_from(sorted(LIBRARY)))
    text = LIBRARY[name]
    for _ in range(draw(st.integers(1, 4))):
        text = draw(mutation(text))
    return name, text


@st.composite
def corrupted_bytes(draw) -> bytes:
    """A bundled schedule's bytes with a few bytes overwritten, or random bytes."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=400))
    data = bytearray(LIBRARY[draw(st.sampled_from(sorted(LIBRARY)))].encode("utf-8"))
    for _ in range(draw(st.integers(1, 4))):
        data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
    return bytes(data)


mutated_library_bytes = mutated_library().map(lambda case: case[1].encode("utf-8"))

# ----------------------------------------------------------------------------- the oracle


def check_error(error: smol_dsl.ScheduleError, text: str | None, path: str) -> None:
    """A ScheduleError names the file, its line and column, shows the offending line, and hints."""
    shown = str(error)
    assert shown.startswith(path), shown
    if error.span is not None:
        assert error.line >= 1 and error.column >= 1, shown
        assert shown.startswith(f"{path}:{error.line}:{error.column}: error: "), shown
    assert error.message and error.message in shown
    if error.hint:
        assert shown.endswith(f"\nhint: {error.hint}"), shown
    if error.span is not None and text is not None:
        # the excerpt is the line the error points at (lines end with "\n", as the parser counts
        # them, or with a lone "\r", which parse reads as one)
        lines = re.sub(r"\r(?!\n)", "\n", text).split("\n")
        assert error.line <= max(1, len(lines)), (error.line, len(lines), shown)
        line = lines[error.line - 1].rstrip("\r") if error.line <= len(lines) else ""
        printable = "".join(c if c.isprintable() else "?" for c in line.expandtabs(1))
        rows = shown.split("\n")
        if printable.strip() and len(rows) >= 3 and "^" in rows[2]:
            excerpt = rows[1][5:]
            assert excerpt and excerpt in printable, f"excerpt {excerpt!r} is not line {error.line}: {line!r}"


def check_schedule(schedule: smol_dsl.Schedule) -> None:
    """A schedule that was accepted evaluates, in every channel, to finite, positive values (at
    every phase and on a dense grid of t, in float32) with a tail of exactly its final value:
    no third outcome."""
    assert schedule.tail_start <= 0.9
    tail = schedule.tail_phases(20)
    assert tail >= 2
    values = np.asarray(schedule.checked_phase_values(20))
    assert values.shape == (20, len(schedule.channels))
    for column, channel in enumerate(schedule.channels):
        curve = schedule.curve(channel)
        cert = schedule.certificates[channel]
        assert 0 < cert.minimum <= cert.maximum and cert.final == curve.final > 0
        phases = values[:, column]
        assert np.all(np.isfinite(phases)) and np.all(phases > 0), phases
        assert np.all(phases[20 - tail :] == np.float32(curve.final)), phases
        dense = np.asarray(curve.value(np.linspace(0.0, 1.0, 4001, dtype=np.float32)))
        assert np.all(np.isfinite(dense)) and np.all(dense > 0), dense


def parse_outcome(text: str, path: str = "fuzz.sched") -> smol_dsl.Schedule | None:
    try:
        schedule = smol_dsl.parse(text, path=path)
    except smol_dsl.ScheduleError as error:
        check_error(error, text, path)
        return None
    assert isinstance(schedule, smol_dsl.Schedule)
    check_schedule(schedule)
    return schedule


def load_outcome(data: bytes, path: Path) -> None:
    path.write_bytes(data)
    try:
        schedule = smol_dsl.load(str(path))
    except smol_dsl.ScheduleError as error:
        try:
            text = data.decode("utf-8-sig")  # what load reads
        except UnicodeDecodeError:
            text = None
        check_error(error, text, str(path))
        return
    check_schedule(schedule)


# ----------------------------------------------------------------------------- parse and load


@settings(max_examples=examples(1000), **COMMON)
@given(language_text | token_soup | any_text)
def test_random_text_parses_or_raises_a_located_schedule_error(text):
    parse_outcome(text)


@settings(max_examples=examples(80), **COMMON)
@given(mutated_library())
def test_mutated_library_files_parse_or_raise_a_located_schedule_error(case):
    name, text = case
    parse_outcome(text, path=name)


@st.composite
def mutated_multi_channel(draw) -> str:
    """A generated multi-channel file (random channels, targets and finals) with one to three edits."""
    text = draw(multi_channel_schedules(max_channels=4, max_body=2)).text
    for _ in range(draw(st.integers(1, 3))):
        text = draw(mutation(text))
    return text


@settings(max_examples=examples(60), **COMMON)
@given(mutated_multi_channel())
def test_mutated_multi_channel_files_parse_or_raise_a_located_schedule_error(text):
    parse_outcome(text)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@settings(max_examples=examples(100), **COMMON)
@given(corrupted_bytes() | mutated_library_bytes)
def test_loading_any_file_gives_a_schedule_or_a_located_schedule_error(fuzz_dir, data):
    load_outcome(data, fuzz_dir / "fuzzed.sched")


@pytest.mark.slow  # verifies every bundled and example schedule
def test_the_fuzzed_library_is_valid_to_begin_with():
    for name, text in LIBRARY.items():
        assert parse_outcome(text, path=name) is not None, name


# ----------------------------------------------------------------------------- the command line


def smol_dsl_command() -> list[str]:
    """The console script of this environment, else one on PATH, else `python -m smol_dsl.cli`."""
    beside = Path(sys.executable).with_name("smol-dsl")
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("smol-dsl")
    return [found] if found else [sys.executable, "-m", "smol_dsl.cli"]


def run_check(paths: list[Path], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*smol_dsl_command(), "check", *map(str, paths)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
        env={**os.environ, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"},
    )


@settings(max_examples=examples(5), **COMMON)
@given(st.lists(mutated_library_bytes | corrupted_bytes(), min_size=2, max_size=2))
def test_cli_check_exits_0_or_2_without_a_traceback(fuzz_dir, files):
    paths = []
    for i, data in enumerate(files):
        path = fuzz_dir / f"cli-{i}.sched"
        path.write_bytes(data)
        paths.append(path)
    result = run_check(paths, fuzz_dir)
    assert "Traceback" not in result.stderr, result.stderr
    assert result.returncode in (0, 2), (result.returncode, result.stderr)
    failing = []
    for path in paths:
        try:
            smol_dsl.load(str(path))
        except smol_dsl.ScheduleError:
            failing.append(path)
    assert result.returncode == (2 if failing else 0), (result.returncode, result.stderr)
    for path in failing:
        assert str(path) in result.stderr


# ----------------------------------------------------------------------------- no code execution

INJECTIONS = (
    'expr __import__("os").system("touch PWNED")',
    "expr __import__('os').system('touch PWNED')",
    "expr eval(\"__import__('os').system('touch PWNED')\")",
    "expr exec(\"open('PWNED', 'w')\")",
    "expr lambda: open('PWNED', 'w')",
    'expr open("PWNED", "w")',
    "expr open(PWNED, w)",
    "expr t.__class__.__mro__",
    "expr ().__class__.__bases__[0].__subclasses__()",
    "expr exp.__globals__",
    "constant __builtins__",
    "expr sympify(PWNED)",
    "expr Symbol(PWNED)",
    "expr oo",
    "expr I",
    "expr getattr(t, PWNED)",
    "linear 1 -> __import__(os)",
    "expr [x for x in ()]",
    "expr 1; import os",
    "expr 1 if t else 2",
)


@pytest.mark.parametrize("shape", INJECTIONS)
def test_code_in_a_schedule_is_never_run(shape, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = f"0% .. 90%: {shape}\n90% .. 100%: tail\n"
    with pytest.raises(smol_dsl.ScheduleError) as caught:
        smol_dsl.parse(text, path="evil.sched")
    check_error(caught.value, text, "evil.sched")
    assert not (tmp_path / "PWNED").exists()


def test_code_in_a_schedule_is_never_run_by_the_cli(tmp_path):
    paths = []
    for i, shape in enumerate(INJECTIONS):
        path = tmp_path / f"evil-{i}.sched"
        path.write_text(f"0% .. 90%: {shape}\n90% .. 100%: tail\n", encoding="utf-8")
        paths.append(path)
    result = run_check(paths, tmp_path)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "PWNED").exists()
    assert all(str(path) in result.stderr for path in paths)
