"""The package's layers import downward only: language -> tasks -> qdax -> rundir -> runner ->
rescoring -> results -> cli, annotation-only imports included (an import under TYPE_CHECKING
still couples the modules). `errors`, `seeds` and `lazy` are the base every layer may use; the package's own names
(`smol_dsl.load`, `__version__`: its front door, over language and tasks) only the CLI."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "smol_dsl"
LAYERS = ("language", "tasks", "qdax", "rundir", "runner", "rescoring", "results", "cli")
BASE = ("errors", "seeds", "lazy")


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every smol_dsl module a file imports, `from smol_dsl import x` as
    `smol_dsl.x`."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "smol_dsl":
                found += [(node.lineno, f"smol_dsl.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, node.module))
    return [(line, name) for line, name in found if name.split(".")[0] == "smol_dsl"]


def layer_of(parts: tuple[str, ...]) -> str | None:
    return parts[0] if parts and parts[0] in LAYERS else None


def front_door(parts: tuple[str, ...]) -> bool:
    """Whether `smol_dsl.<parts>` is one of the package's own names, not one of its modules."""
    return bool(parts) and not (PACKAGE / parts[0]).is_dir() and not (PACKAGE / f"{parts[0]}.py").is_file()


def test_every_import_goes_down_the_layers():
    against = []
    for path in sorted(PACKAGE.rglob("*.py")):
        layer = layer_of(path.relative_to(PACKAGE).parts)
        if layer is None:
            continue
        for line, module in imported_modules(path):
            parts = tuple(module.split(".")[1:])
            target = layer_of(parts)
            if target is None and parts and parts[0] in BASE:
                continue
            if target is None and front_door(parts) and layer == LAYERS[-1]:
                continue
            if target is None or LAYERS.index(target) > LAYERS.index(layer):
                against.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {layer} imports {module}")
    assert against == []


def test_the_check_sees_an_import_against_the_layers(tmp_path):
    """The walk above finds imports of every form, so an empty list means something."""
    sample = tmp_path / "sample.py"
    sample.write_text(
        "from __future__ import annotations\nfrom typing import TYPE_CHECKING\nimport smol_dsl.runner.engine\n"
        "from smol_dsl import results\nif TYPE_CHECKING:\n    from smol_dsl.cli import main\n"
        "def lazily():\n    from smol_dsl.runner.layout import default_runs_per_step\n"
    )
    assert [name for _, name in imported_modules(sample)] == [
        "smol_dsl.runner.engine",
        "smol_dsl.results",
        "smol_dsl.cli",
        "smol_dsl.runner.layout",
    ]


def test_the_presets_have_one_definition_below_the_runner_and_the_results():
    """The run directory's presets are the very objects the runner's public names give."""
    import smol_dsl.rundir.presets
    import smol_dsl.runner
    import smol_dsl.runner.config

    for module in (smol_dsl.runner, smol_dsl.runner.config):
        assert module.preset_config is smol_dsl.rundir.presets.preset_config
        assert module.PRESETS is smol_dsl.rundir.presets.PRESETS
