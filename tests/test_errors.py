"""Every malformed schedule gets one located error with the offending text and a hint."""

from __future__ import annotations

import pytest
from checking import check_cli

import smol_dsl
from smol_dsl import ScheduleError
from smol_dsl.cli import main

TAIL = "90% .. 100%: tail\n"

# (source, line, column, words in the message, words in the hint)
CASES = {
    "missing colon": ("0% .. 90% linear 1 -> 2\n" + TAIL, 1, 11, "unexpected 'linear'", "START .. END: SHAPE"),
    "missing range dots": ("0% 90%: tail\n", 1, 4, "unexpected", "START .. END"),
    "misspelled kind": ("0% .. 90%: lineal 1 -> 2\n" + TAIL, 1, 12, "unexpected 'lineal'", "did you mean `linear`"),
    "caret power": ("0% .. 90%: expr t^2\n" + TAIL, 1, 18, "unexpected character '^'", "**"),
    "single quotes": ("name 'x'\n0% .. 100%: tail\n", 1, 6, "unexpected character", "double quotes"),
    "linear without arrow": ("0% .. 90%: linear 1 2\n" + TAIL, 1, 21, "unexpected", "`linear` takes two values"),
    "bell without peak": ("0% .. 90%: bell 1 -> 2 -> 1\n" + TAIL, 1, 24, "unexpected", "`bell` is written"),
    "random with arrow": ("0% .. 90%: random 1 -> 2\n" + TAIL, 1, 21, "unexpected", "`random` is written"),
    "end of file": ("0% .. 90%: linear 1 ->", 1, 23, "unexpected end", "expected"),
    "two statements on a line": (
        "0% .. 90%: constant 1 90% .. 100%: tail\n",
        1,
        23,
        "unexpected",
        "one statement per line",
    ),
    "empty file": ("", 1, 1, "empty schedule", "segments covering"),
    "only comments": ("# nothing here\n\n   # still nothing\n", 1, 1, "empty schedule", "segments covering"),
    "control character": ("0% .. 100%: tail\x00\n", 1, 17, "control character", "binary"),
    "no segments": ('name "x"\n', 1, 1, "no segments", "add segments"),
    "unknown name": (
        "let peak = 1.4\n0% .. 90%: linear 1 -> peek\n" + TAIL,
        2,
        24,
        "unknown name `peek`",
        "did you mean `peak`",
    ),
    "nan": ("0% .. 90%: constant nan\n" + TAIL, 1, 21, "unknown name `nan`", "finite"),
    "inf": ("0% .. 90%: linear 1 -> inf\n" + TAIL, 1, 24, "unknown name `inf`", "finite"),
    "huge literal": ("0% .. 90%: constant 1e400\n" + TAIL, 1, 21, "out of range", "64-bit float"),
    "huge exponent literal": ("0% .. 90%: constant 1e99999\n" + TAIL, 1, 21, "out of range", "64-bit float"),
    "huge power": ("0% .. 90%: constant 10**10**10\n" + TAIL, 1, 21, "power out of range", "sensible alpha"),
    "unknown function": (
        "0% .. 90%: expr 1 + sinh(t)\n" + TAIL,
        1,
        21,
        "unknown function `sinh`",
        "did you mean `sin`",
    ),
    "arity": ("0% .. 90%: expr 1 + exp(t, 2)\n" + TAIL, 1, 21, "takes 1 argument", "exp(x)"),
    "min arity": ("0% .. 90%: expr min(t)\n" + TAIL, 1, 17, "two or more", "min(a, b)"),
    "division by zero": ("0% .. 90%: constant 1/0\n" + TAIL, 1, 21, "division by zero", "0"),
    "let depends on t": ("let a = t\n0% .. 100%: tail\n", 1, 9, "unknown name `t`", "only defined inside an `expr`"),
    "constant depends on t": ("0% .. 90%: constant 1 + t\n" + TAIL, 1, 25, "unknown name `t`", "`expr`"),
    "let shadows builtin": ("let exp = 2\n0% .. 100%: tail\n", 1, 1, "`exp` is a built-in name", "another name"),
    "let twice": ("let a = 2\nlet a = 3\n0% .. 100%: tail\n", 2, 1, "`a` is already defined", "another name"),
    "name twice": ('name "a"\nname "b"\n0% .. 100%: tail\n', 2, 1, "given twice (first on line 1)", "at most one"),
    "position beyond the run": ("0 .. 90: constant 1\n", 1, 6, "outside the run", "not `90`"),
    "irrational position": ("0% .. pi/4: constant 1\npi/4 .. 100%: tail\n", 1, 7, "plain percentage", "`90%`"),
    "empty segment": ("0% .. 50%: constant 1\n50% .. 40%: tail\n", 2, 1, "is empty", "after its start"),
    "gap": ("0% .. 40%: linear 1 -> 2\n50% .. 100%: tail\n", 2, 1, "gap between 40% and 50%", "start it at 40%"),
    "overlap": ("0% .. 60%: constant 2\n50% .. 100%: tail\n", 2, 1, "overlap between 50% and 60%", "must not overlap"),
    "late start": ("10% .. 100%: tail\n", 1, 1, "leave 0% .. 10% uncovered", "start the first segment at 0%"),
    "early end": ("0% .. 95%: tail\n", 1, 1, "leave 95% .. 100% uncovered", "95% .. 100%: tail"),
    "no tail": ("0% .. 100%: linear 2 -> 1\n", 1, 1, "no alpha = 1 tail", "90% .. 100%: tail"),
    "short tail": ("0% .. 95%: linear 2 -> 1\n95% .. 100%: tail\n", 2, 1, "only from 95%", "90% .. 100%: tail"),
    "zero alpha": ("0% .. 90%: linear 0 -> 1\n" + TAIL, 1, 1, "above 0", "gear"),
    "negative alpha": ("0% .. 90%: constant -0.5\n" + TAIL, 1, 1, "goes down to -0.5", "gear"),
    "negative inside": ("0% .. 90%: expr 1 - 2*sin(10*t)\n" + TAIL, 1, 1, "above 0", "gear"),
    "log of negative": (
        "0% .. 90%: expr log(t - 0.5)\n" + TAIL,
        1,
        1,
        "a logarithm needs a positive argument, but t - 1/2 goes down to -0.5",
        "logarithms of positive values",
    ),
    "sqrt of negative": (
        "0% .. 90%: expr 1 + sqrt(0.5 - u)\n" + TAIL,
        1,
        1,
        "a square root needs a non-negative argument, but 1/2 - 10*t/9 goes down to -0.5",
        "square roots",
    ),
    "pole": (
        "0% .. 90%: expr 1 + 1/(t - 0.5)\n" + TAIL,
        1,
        1,
        "a division needs a non-zero argument, but t - 1/2 ranges over -0.5 .. 0.4",
        "divisions away from zero",
    ),
    "reserved word": ("let tail = 2\n0% .. 100%: tail\n", 1, 1, "`tail` is a reserved word", "reserved: and, at, bell"),
    "dangling decimal point": (
        "0% .. 90%: linear 1. -> 2\n" + TAIL,
        1,
        20,
        "unexpected character '.'",
        "digits after its decimal point",
    ),
    "tiny literal": ("0% .. 90%: constant 1 + 1e-350\n" + TAIL, 1, 25, "out of range", "2.2e-308"),
    "above bounds": (
        "bounds 0.5 .. 1.5\n0% .. 90%: linear 1.6 -> 1\n" + TAIL,
        2,
        1,
        "0.1 above the declared bound 1.5",
        "widen",
    ),
    "below bounds": (
        "bounds 0.5 .. 1.5\n0% .. 90%: linear 0.4 -> 1\n" + TAIL,
        2,
        1,
        "0.1 below the declared bound 0.5",
        "widen",
    ),
    "reversed bounds": ("bounds 1.5 .. 0.5\n0% .. 100%: tail\n", 1, 1, "reversed", "bounds 0.5 .. 1.5"),
    "false monotone": (
        "0% .. 90%: linear 1 -> 2 decreasing\n" + TAIL,
        1,
        1,
        "declared decreasing",
        "remove `decreasing`",
    ),
    "random not monotone": ("0% .. 90%: random 1 .. 2 increasing\n" + TAIL, 1, 1, "declared increasing", "remove"),
    "not continuous": (
        "continuous\n0% .. 90%: linear 2 -> 1.5\n" + TAIL,
        3,
        1,
        "jump of -0.5 at 90%",
        "drop `continuous`",
    ),
    "bell peak outside": (
        "0% .. 90%: bell 1 -> 2 at 95% -> 1\n" + TAIL,
        1,
        27,
        "outside the segment",
        "strictly inside",
    ),
    "bell width": ("0% .. 90%: bell 1 -> 2 at 45% -> 1 width 0\n" + TAIL, 1, 42, "must be positive", "width 15%"),
    "reversed random": ("0% .. 90%: random 1.5 .. 0.5\n" + TAIL, 1, 19, "reversed", "random 0.5 .. 1.5"),
    "zero resolution": ("0% .. 90%: random 0.5 .. 1.5 every 0%\n" + TAIL, 1, 36, "must be positive", "every 1%"),
    "too many draws": ("0% .. 90%: random 0.5 .. 1.5 every 1e-9\n" + TAIL, 1, 36, "random draws", "coarser"),
    "extinction above one": ("extinction 150%\n0% .. 100%: tail\n", 1, 1, "outside 0 .. 1", "extinction 5%"),
    "negative extinction": ("extinction -0.1\n0% .. 100%: tail\n", 1, 1, "outside 0 .. 1", "probability"),
    "alpha beyond float32": ("0% .. 90%: constant 1e300\n" + TAIL, 1, 1, "beyond float32", "modest"),
    "final beyond float32": ("final 1e39\n0% .. 100%: tail\n", 2, 1, "beyond float32", "modest"),
    "channel final beyond float32": ("channel mass\nfinal 1e39\n0% .. 100%: tail\n", 3, 1, "mass = 1e+39", "modest"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_error_is_located_and_hinted(case):
    source, line, column, message, hint = CASES[case]
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse(source, path="bad.sched")
    error = caught.value
    assert message in error.message, error
    assert (error.line, error.column) == (line, column), error
    assert error.hint and hint in error.hint, error
    text = str(error)
    assert text.startswith(f"bad.sched:{line}:{column}: error: ")
    assert f"hint: {error.hint}" in text
    if source.strip():
        # the offending line is shown with a caret under the offending text
        shown = source.splitlines()[line - 1].replace("\x00", "?")
        lines = text.splitlines()
        assert lines[1].strip() == shown.strip()
        assert lines[2].index("^") == lines[1].index(shown.strip()[0]) + (column - 1) - (
            len(shown) - len(shown.lstrip())
        )


def test_only_one_error_is_reported_the_first():
    source = "0% .. 40%: linear 1 -> 2\n50% .. 60%: constant -1\n70% .. 100%: tail\n"
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse(source)
    assert "gap between 40% and 50%" in caught.value.message
    assert str(caught.value).count("error:") == 1


def test_non_utf8_file_is_located(tmp_path):
    path = tmp_path / "junk.sched"
    path.write_bytes(b"0% .. 100%: tail\n# caf\xe9\n")
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.load(path)
    assert (caught.value.line, caught.value.column) == (2, 6)
    assert "not UTF-8" in caught.value.message
    assert str(path) in str(caught.value)


def test_a_directory_is_not_a_schedule(tmp_path):
    with pytest.raises(ScheduleError, match="not a file"):
        smol_dsl.load(tmp_path)


def test_deeply_nested_expression_is_refused():
    source = "0% .. 90%: expr 1 + " + "-" * 3000 + "1\n" + TAIL
    with pytest.raises(ScheduleError, match="nested too deeply"):
        smol_dsl.parse(source)


def test_long_lines_are_clipped_around_the_caret():
    source = "0% .. 90%: expr " + "t + " * 100 + "$\n" + TAIL
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse(source)
    excerpt, caret = str(caught.value).splitlines()[1:3]
    assert len(excerpt) <= 130
    assert excerpt[caret.index("^")] == "$"


def test_reserved_words_are_the_grammar_keywords():
    from smol_dsl.language.grammar import reserved_words

    assert reserved_words() == set(
        "name description let bounds extinction continuous constant linear bell random expr tail "
        "at width every increasing decreasing channel final pace when within phases and or".split()
    )


@pytest.mark.parametrize(
    "body",
    [
        "1 + 0.3 * tanh(u) * cos(u)",
        "max(1, 1.5 - abs(u - 0.3))",
        pytest.param("1 + 0.2*tanh(sin(3*u) + cos(5*u))", marks=pytest.mark.slow),  # a long proof
        "log(t + 1) + exp(-t)",
        "1 + sqrt(u)",
        "sin(t)**2 + cos(t)**2 + 0.5*(1 - u)",
    ],
)
def test_finite_real_expressions_are_accepted(body):
    schedule = smol_dsl.parse(f"0% .. 90%: expr {body}\n" + TAIL)
    piece = schedule.certificate.pieces[0]
    assert 0 < piece.minimum <= piece.maximum <= 2


def test_an_exact_identity_meets_tight_bounds():
    schedule = smol_dsl.parse("bounds 1 .. 1.5\n0% .. 50%: linear 1.5 -> 1\n50% .. 100%: expr sin(t)**2 + cos(t)**2\n")
    assert schedule.certificate.minimum == 1.0
    assert schedule.tail_start == 0.5


# ----------------------------------------------------------------------------- numbers


@pytest.mark.parametrize(
    ("text", "column", "hint"),
    [
        ("constant 1\u06605", 22, "ARABIC-INDIC DIGIT ZERO"),
        ("constant \uff11.5", 21, "FULLWIDTH DIGIT ONE"),
        ("constant 1.5\u00b2", 24, "SUPERSCRIPT TWO"),
        ("linear 1.5 \u2212> 1", 23, "write the ASCII `-`"),
        ("constant 1\u00b75", 22, "write the ASCII `*`"),
    ],
)
def test_numbers_are_ascii_digits_only(text, column, hint, tmp_path, capsys):
    code, err = check_cli(tmp_path, f"0% .. 90%: {text}\n90% .. 100%: tail\n", capsys)
    assert code == 2
    assert f"hostile.sched:1:{column}: error: unexpected character" in err
    assert hint in err


def test_an_oversized_let_is_out_of_range_not_a_log_of_a_negative(tmp_path, capsys):
    code, err = check_cli(tmp_path, "let big = 1e300 * 1e300\n0% .. 90%: constant 1\n90% .. 100%: tail\n", capsys)
    assert code == 2
    assert "`let big` is 1.00E+600, out of range" in err
    assert "log" not in err and "square root" not in err


def test_a_final_beyond_float32_is_a_located_refusal_in_every_command(tmp_path, capsys):
    text = "channel mass\nfinal 1e39\n0% .. 100%: tail\n"
    code, err = check_cli(tmp_path, text, capsys)
    assert code == 2 and "hostile.sched:3:1: error:" in err and "beyond float32" in err
    for command in (["run", "walker2d"], ["sweep", "walker2d"]):
        code = main([*command, str(tmp_path / "hostile.sched"), "--dry-run", "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and "hostile.sched:3:1: error:" in err and "Traceback" not in err, err


def test_lines_may_end_in_a_lone_carriage_return():
    lf = "0% .. 90%: linear 1 -> 2\n90% .. 100%: tail\n"
    schedule = smol_dsl.parse(lf.replace("\n", "\r"))
    assert schedule.source == lf and schedule.segments == smol_dsl.parse(lf).segments
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse("0% .. 90%: linear 1 -> 2\r90% .. 100%: oops\r", path="mac.sched")
    assert (caught.value.line, caught.value.column) == (2, 14) and "unexpected 'oops'" in caught.value.message
