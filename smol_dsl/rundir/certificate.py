"""certificate.json and certificate.txt: what was proven about a run's schedule, and the
final body it ends on; written when the run is set up, read by `report`."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.language.channels import Channel
from smol_dsl.rundir.files import read_text
from smol_dsl.rundir.layout import RunDirectoryError, leave_out

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def source_digest(source: str) -> str:
    """The SHA-256 of a schedule file's text (UTF-8), in hex: what certificate.json proves."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def certificate_record(schedule: Schedule) -> dict[str, Any]:
    """certificate.json's contents: the schedule's name, the digest of the text it proves
    (`source_digest`), where its final-body tail starts (the latest of its channels'), plain
    gear's certificate, its final body and every channel's certificate."""
    record = {
        "name": schedule.name,
        SOURCE_DIGEST: source_digest(schedule.source),
        "tail_start": float(schedule.tail_start),
        **schedule.certificate.to_dict(),
    }
    record["tail_start"] = float(schedule.tail_start)  # the schedule's (every channel's), not plain gear's
    record["final_body"] = {channel.name: value for channel, value in schedule.final_body.items()}
    record["channels"] = {channel.name: cert.to_dict() for channel, cert in schedule.certificates.items()}
    return record


SOURCE_DIGEST = "schedule_sha256"
"""certificate.json's entry for the digest of schedule.sched's text."""


def certificate_text(schedule: Schedule) -> str:
    """The certificate as `smol-dsl check` prints it: one per scheduled channel."""
    return schedule.certificates_text()


@dataclass(frozen=True)
class CertificateRecord:
    """What certificate.json says of a run's schedule."""

    name: str
    tail_start: float  # where every channel is at its final value for good
    final_body: dict[str, float]  # the channels whose final factor is not 1, by name
    channels: tuple[Channel, ...]  # the scheduled channels, in declared order
    source_digest: str | None = None  # schedule.sched's SHA-256 (None: a run set up before it was recorded)


def read_certificate(path: Path) -> CertificateRecord:
    """certificate.json, checked: the schedule's name, the start of its final-body tail, its
    final body and its channels."""
    fix = f"rerun the run, {leave_out(path.parent)}"
    try:
        data = json.loads(read_text(path))
    except (json.JSONDecodeError, RecursionError) as error:
        raise RunDirectoryError(f"{path}: not valid JSON ({error}); {fix}") from None
    name = data.get("name") if isinstance(data, dict) else None
    tail = data.get("tail_start") if isinstance(data, dict) else None
    if not isinstance(name, str) or not name:
        raise RunDirectoryError(f'{path}: no schedule name ("name"); {fix}')
    if not isinstance(tail, int | float) or isinstance(tail, bool) or not 0 <= tail <= 1:
        raise RunDirectoryError(
            f'{path}: "tail_start" must be a number from 0 to 1, not {json.dumps(tail)[:40]}; {fix}'
        )
    final = data.get("final_body", {})  # without "final_body": the standard body, every factor 1
    if not isinstance(final, dict) or not all(
        isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and value > 0
        for value in final.values()
    ):
        raise RunDirectoryError(f'{path}: "final_body" must map channels to factors above 0; {fix}')
    declared = data.get("channels", {"gear": None})  # without "channels": a schedule of plain gear alone
    try:
        channels = tuple(Channel.parse(name) for name in declared) if isinstance(declared, dict) else ()
    except ValueError as error:
        raise RunDirectoryError(f'{path}: "channels" names {error}; {fix}') from None
    if not channels:
        raise RunDirectoryError(f'{path}: "channels" must name the schedule\'s channels; {fix}')
    digest = data.get(SOURCE_DIGEST)
    if digest is not None and not (
        isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)
    ):
        raise RunDirectoryError(f'{path}: "{SOURCE_DIGEST}" must be a SHA-256 in hex (64 digits); {fix}')
    body = {str(channel): float(value) for channel, value in final.items() if value != 1}
    return CertificateRecord(name, float(tail), body, channels, digest)
