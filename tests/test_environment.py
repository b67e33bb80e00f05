"""environment.json (rundir/environment.py): every run records the software and hardware it
ran under; a resume under another record is refused unless allowed (and then recorded), and
a report refuses runs of different records in one table unless told to."""

from __future__ import annotations

import json
from importlib import metadata

import jax
import pytest
from hypothesis import given
from hypothesis import strategies as st
from small_runs import RUN, cli, copy_of

from smol_dsl.rundir import (
    ENVIRONMENT_FILE,
    describe_environment,
    environment_differences,
    read_environment,
    read_environment_changes,
)
from smol_dsl.rundir.environment import COMPARED, MISSING_RECORD


class Device:
    def __init__(self, platform: str = "cpu", device_kind: str = "cpu") -> None:
        self.platform, self.device_kind = platform, device_kind


def test_the_record_names_versions_devices_and_processor():
    record = describe_environment(jax.devices())
    assert record["packages"]["jax"] == jax.__version__
    assert record["packages"]["brax"] == metadata.version("brax")
    assert record["packages"]["qdax"] == metadata.version("qdax")
    assert record["smol_dsl"] == metadata.version("smol-dsl")
    assert record["devices"] == {
        "platform": "cpu",
        "kinds": sorted({d.device_kind for d in jax.devices()}),
        "count": len(jax.devices()),
    }
    assert record["processor"]["model"]
    assert json.loads(json.dumps(record)) == record  # plain JSON


def test_differences_name_what_changes_the_numbers_and_only_that():
    record = describe_environment([Device(), Device()])
    other = json.loads(json.dumps(record))
    other["packages"]["jax"] = "0.0.1"
    other["devices"]["count"] = 1
    other["processor"]["vector_extensions"] = ["sse4_2"]
    other["host"] = "elsewhere"  # recorded, not compared
    other["system"] = "another kernel"
    differences = environment_differences(other, record)
    assert f"jax 0.0.1 -> {record['packages']['jax']}" in differences
    assert "devices count 1 -> 2" in differences
    assert any(d.startswith("processor vector_extensions sse4_2 -> ") for d in differences)
    assert len(differences) == 3
    assert environment_differences(record, record) == []


records = st.fixed_dictionaries(
    {
        "python": st.sampled_from(["3.11.7", "3.13.0"]),
        "smol_dsl": st.just("0.1.0"),
        "commit": st.one_of(st.none(), st.sampled_from(["abc", "abc+changes"])),
        "packages": st.dictionaries(st.sampled_from(["jax", "brax", "qdax"]), st.sampled_from(["1", "2"])),
        "devices": st.fixed_dictionaries({"platform": st.just("cpu"), "count": st.integers(1, 4)}),
        "processor": st.fixed_dictionaries({"model": st.sampled_from(["a", "b"])}),
        "host": st.text(max_size=3),
    }
)


@given(records, records)
def test_two_records_differ_exactly_where_a_compared_entry_does(first, second):
    differences = environment_differences(first, second)
    assert environment_differences(first, first) == []
    assert bool(differences) == any(first.get(key) != second.get(key) for key in COMPARED)


def _with_record(run, **changes):
    """A run directory's environment.json as if it had been started elsewhere."""
    path = run / ENVIRONMENT_FILE
    data = json.loads(path.read_text())
    for key, value in changes.items():
        section, _, name = key.partition(".")
        if name:
            data["environment"][section][name] = value
        else:
            data["environment"][section] = value
    path.write_text(json.dumps(data, indent=2))


def test_every_run_records_its_environment(small_run):
    recorded = read_environment(small_run)
    assert recorded is not None
    assert environment_differences(recorded, describe_environment(jax.local_devices())) == []
    assert read_environment_changes(small_run) == []


def test_a_resume_under_another_environment_is_refused_and_changes_nothing(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    _with_record(out, **{"packages.jax": "0.0.1", "devices.count": 16})
    before = {path.name: path.read_bytes() for path in out.iterdir() if path.is_file()}
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2, err
    assert f"{out} was started under another environment (environment.json): jax 0.0.1 -> {jax.__version__}" in err
    assert f"devices count 16 -> {len(jax.local_devices())}" in err
    assert "--allow-environment-change" in err
    after = {path.name: path.read_bytes() for path in out.iterdir() if path.is_file()}
    assert after == before


def test_a_resume_allowed_under_another_environment_records_the_change(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    _with_record(out, **{"packages.jax": "0.0.1"})
    code, err = cli([*RUN, "--out", str(out), "--resume", "--allow-environment-change"], capsys)
    assert code == 0, err
    assert read_environment(out)["packages"]["jax"] == "0.0.1"  # what it was started under
    (change,) = read_environment_changes(out)
    assert change["differences"] == [f"jax 0.0.1 -> {jax.__version__}"]
    assert change["environment"]["packages"]["jax"] == jax.__version__


def _started_elsewhere(run):
    _with_record(run, **{"packages.brax": "0.0.1", "processor.model": "another processor"})
    return f"was started under another environment than {run.parent / 'walker2d-human-seed0'}", (
        f"brax {metadata.version('brax')} -> 0.0.1"
    )


def _resumed_elsewhere(run):
    path = run / ENVIRONMENT_FILE
    data = json.loads(path.read_text())
    data["changes"].append({"environment": data["environment"], "differences": ["devices count 2 -> 1"]})
    path.write_text(json.dumps(data))
    return "was resumed under another environment", "devices count 2 -> 1"


def _without_record(run):
    (run / ENVIRONMENT_FILE).unlink()
    return "has no environment.json", f"unlike {run.parent / 'walker2d-human-seed0'}"


@pytest.mark.parametrize("mix", [_started_elsewhere, _resumed_elsewhere, _without_record])
def test_a_report_refuses_mixed_environments_and_writes_down_what_it_was_allowed(small_run, tmp_path, capsys, mix):
    """Runs started elsewhere, resumed elsewhere, or with no record beside runs with one are
    refused; allowed, the report's table.md and index.html say how they mix."""
    copy_of(small_run, tmp_path / "runs", "walker2d-human-seed0")
    second = copy_of(small_run, tmp_path / "runs", "walker2d-human-seed1")
    config = json.loads((second / "config.json").read_text())
    (second / "config.json").write_text(json.dumps({**config, "seed": 1}))
    what, detail = mix(second)
    report = ["report", str(tmp_path / "runs"), "-o", str(tmp_path / "report"), "--no-gaits"]
    code, err = cli(report, capsys)
    assert code == 2, err
    assert f"not all produced under one environment: {second} {what}" in err and detail in err, err
    assert "--allow-mixed-environments" in err and not (tmp_path / "report").exists()
    code, err = cli([*report, "--allow-mixed-environments"], capsys)
    assert code == 0, err
    assert f"note: allowed to mix environments: {second} {what}" in err
    for page in ("table.md", "index.html"):
        text = (tmp_path / "report" / page).read_text()
        assert "mixed environment" in text and what in text and "environment" in text, page


def test_a_report_of_one_environment_names_it(small_run, tmp_path, capsys):
    code, err = cli(["report", str(small_run), "-o", str(tmp_path / "report"), "--no-gaits"], capsys)
    assert code == 0, err
    table = (tmp_path / "report" / "table.md").read_text()
    assert f"jax {jax.__version__}" in table and "mixed environment" not in table
    assert "**budget**" in table and "**settings**" in table


@pytest.mark.parametrize("text", ["{", "[]", '{"environment": {}}'])
def test_a_damaged_environment_json_is_named(small_run, tmp_path, capsys, text):
    out = copy_of(small_run, tmp_path)
    (out / ENVIRONMENT_FILE).write_text(text)
    code, err = cli(["report", str(out), "-o", str(tmp_path / "report"), "--no-gaits"], capsys)
    assert code == 2 and f"{out / ENVIRONMENT_FILE}" in err, err


def test_a_resume_without_environment_json_is_refused_unless_allowed_and_then_recorded(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    (out / ENVIRONMENT_FILE).unlink()
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{out} holds no {ENVIRONMENT_FILE}" in err and "--allow-environment-change" in err, err
    assert not (out / ENVIRONMENT_FILE).exists()
    code, err = cli([*RUN, "--out", str(out), "--resume", "--allow-environment-change"], capsys)
    assert code == 0, err
    assert read_environment(out) == {}  # the start is unknown
    (change,) = read_environment_changes(out)
    assert change["differences"] == [MISSING_RECORD]
    assert environment_differences(change["environment"], describe_environment(jax.local_devices())) == []
