"""The run directory: the one definition of what `smol-dsl run` and `sweep` write and what
`smol-dsl report` reads. Both the runner and the results read and write through this
package, which sits between the tasks and the runner; nothing here imports JAX, Brax, QDax
or Flax, and sympy, mpmath and Lark are loaded only when a schedule is verified (`read_run`
verifies schedule.sched; reading config, metrics or archive does not).

Modules, one concept each:

- `layout`: the file names (`*_FILE`; `FILES` says what each holds; a sweep's `run_name`
  and `sweep_checkpoint_file`), `is_run_directory`,
  `RunDirectoryError`;
- `files`: atomic writes (`atomic_write`, `write_text`, `write_npz`; their temporary files,
  `remove_stale_temporaries`), `read_text` and `read_json_object`;
- `config`: `RunConfig`, config.json, and its checked reader `read_config`;
- `presets`: a run's settings by name (`PRESETS`: `paper`, `quick`), `preset_config`;
- `metrics`: metrics.csv's columns (`METRICS_SCHEMA`, one `Column` per column; a run's body
  is one column per channel: `column_name`, `metrics_schema(channels, clocks)`, `scheduled_columns`,
  and a row's values `body_columns`; a schedule's `schedule_schema`; a paced run's
  `development_names` and the bodies its rows log, `trained_bodies`; the events of a
  boundary's row, `BOUNDARY_EVENTS`) and its writer `MetricsLog`;
- `metrics_reader`: the checked reader `read_metrics` (`schema_of_header`), and where the
  final-body tail starts (`first_tail_phase`, `final_body_evaluations`);
- `certificate`: certificate.json and .txt;
- `archive`: archive.npz (`write_archive`, `load_archive`, `read_final_archive`);
- `environment`: environment.json, what a run ran under (`describe_environment`,
  `environment_differences`);
- `checkpoint`: a checkpoint's arrays (`checkpoint_contents`; `open_checkpoint` checks one
  before it is loaded) and each run's progress in it (`RunState`);
- `sweep`: sweep.json (`sweep_description`, `sweep_differences`);
- `record`: a run directory as a whole (`write_run_files`; `read_run` -> `RunRecord`);
- `robustness`: robustness.csv, what `smol-dsl robustness` measured of finished runs
  (`RobustnessRow`, `write_robustness`, `read_robustness`).

Writing, for the runner (every file is written atomically, and an OSError names the file
that could not be written):

    write_run_files(directory, config, schedule, environment) -> list[Path]   # config.json, environment.json,
                                                       # schedule.sched, certificate.*
    log = MetricsLog(directory / METRICS_FILE, rows)   # exactly `rows`, written atomically
    log.append(metrics_row(generation=..., phase=..., alpha=..., event="train", ...))
    write_archive(directory / ARCHIVE_FILE, arrays)    # {"genotypes/<param path>": (C, ...), "fitnesses",
                                                       #  "descriptors", "centroids", "lanes"}; `filled` is derived

Reading, for the report and for users:

    read_run(directory) -> RunRecord     # every file checked; a RunDirectoryError names file and line
    read_config, read_certificate, read_metrics, read_final_archive
    load_archive(path) -> Archive        # the final archive with its policies, as nested dicts
"""

from smol_dsl.rundir.archive import (
    ARCHIVE_ARRAYS,
    GENOTYPES,
    LANES,
    Archive,
    FinalArchive,
    load_archive,
    read_final_archive,
    write_archive,
)
from smol_dsl.rundir.certificate import CertificateRecord, certificate_record, certificate_text, read_certificate
from smol_dsl.rundir.config import RunConfig, read_config
from smol_dsl.rundir.environment import (
    RESUME_COMPARED,
    describe_environment,
    environment_differences,
    latest_environment,
    read_environment,
    read_environment_changes,
    record_environment_change,
    scoring_layout,
)
from smol_dsl.rundir.files import atomic_write, read_text, write_npz, write_text
from smol_dsl.rundir.layout import (
    ARCHIVE_FIGURE,
    ARCHIVE_FILE,
    CERTIFICATE_FILE,
    CERTIFICATE_TEXT_FILE,
    CHECKPOINT_FILE,
    CONFIG_FILE,
    ENVIRONMENT_FILE,
    FILES,
    LOCK_FILE,
    METRICS_FIGURE,
    METRICS_FILE,
    ROBUSTNESS_FILE,
    RUN_MARKERS,
    SCHEDULE_FILE,
    SWEEP_CHECKPOINT_FILE,
    SWEEP_FILE,
    SWEEP_FILES,
    RunDirectoryError,
    files_markdown,
    is_run_directory,
)
from smol_dsl.rundir.metrics import (
    ALPHA,
    BOUNDARY_EVENTS,
    EVENTS,
    HOLD,
    METRIC_FIELDS,
    METRICS_SCHEMA,
    REEVALUATION,
    REEVALUATION_FIELDS,
    SCORES,
    Column,
    MetricsLog,
    MetricsSchema,
    body_columns,
    channel_column,
    column_name,
    development_names,
    metrics_row,
    metrics_schema,
    schedule_schema,
    scheduled_columns,
    trained_bodies,
)
from smol_dsl.rundir.metrics_reader import final_body_evaluations, first_tail_phase, read_metrics, schema_of_header
from smol_dsl.rundir.presets import PRESETS, preset_config
from smol_dsl.rundir.record import RunRecord, read_run, write_run_files
from smol_dsl.rundir.robustness import MEDIAN, RobustnessRow, read_robustness, write_robustness

__all__ = [
    "ALPHA",
    "ARCHIVE_ARRAYS",
    "ARCHIVE_FIGURE",
    "ARCHIVE_FILE",
    "BOUNDARY_EVENTS",
    "CERTIFICATE_FILE",
    "CERTIFICATE_TEXT_FILE",
    "CHECKPOINT_FILE",
    "CONFIG_FILE",
    "ENVIRONMENT_FILE",
    "EVENTS",
    "FILES",
    "GENOTYPES",
    "HOLD",
    "LANES",
    "LOCK_FILE",
    "MEDIAN",
    "METRICS_FIGURE",
    "METRICS_FILE",
    "METRICS_SCHEMA",
    "METRIC_FIELDS",
    "PRESETS",
    "REEVALUATION",
    "REEVALUATION_FIELDS",
    "RESUME_COMPARED",
    "ROBUSTNESS_FILE",
    "RUN_MARKERS",
    "SCHEDULE_FILE",
    "SCORES",
    "SWEEP_CHECKPOINT_FILE",
    "SWEEP_FILE",
    "SWEEP_FILES",
    "Archive",
    "CertificateRecord",
    "Column",
    "FinalArchive",
    "MetricsLog",
    "MetricsSchema",
    "RobustnessRow",
    "RunConfig",
    "RunDirectoryError",
    "RunRecord",
    "atomic_write",
    "body_columns",
    "certificate_record",
    "certificate_text",
    "channel_column",
    "column_name",
    "describe_environment",
    "development_names",
    "environment_differences",
    "files_markdown",
    "final_body_evaluations",
    "first_tail_phase",
    "is_run_directory",
    "latest_environment",
    "load_archive",
    "metrics_row",
    "metrics_schema",
    "preset_config",
    "read_certificate",
    "read_config",
    "read_environment",
    "read_environment_changes",
    "read_final_archive",
    "read_metrics",
    "read_robustness",
    "read_run",
    "read_text",
    "record_environment_change",
    "schedule_schema",
    "scheduled_columns",
    "schema_of_header",
    "scoring_layout",
    "trained_bodies",
    "write_archive",
    "write_npz",
    "write_robustness",
    "write_run_files",
    "write_text",
]
