"""Rebuild docs/language.md from docs/tools/language.md.in, running every example.

Usage, from anywhere, with the Python of an environment where smol-dsl is installed:

    python docs/tools/build_language.py [OUTPUT]

OUTPUT defaults to docs/language.md next to this folder. The examples run with the
`smol-dsl` found on PATH, or with `python -m smol_dsl.cli` when there is none, in a fresh
temporary directory, so the file names in their messages are the bare names of the
template. Python code, and `python` in console commands, runs with the interpreter that
runs this script. JAX is kept on the CPU (JAX_PLATFORMS=cpu) so that the outputs do not
depend on the machine's devices. A full build takes about two minutes.

The template is Markdown. These fenced blocks are directives; all others are copied as
they are, and any block may be indented (inside a list item):

```sched file=NAME [nonl]
    Writes the block to NAME (with a final newline unless `nonl` is given) and shows it
    as a ```sched block. A later ```check block checks the most recent such file.
```check [ok]
    Runs `smol-dsl check` on that file and shows its stdout and stderr as a ```text
    block. With `ok` the check must pass (exit status 0); without it, it must fail with
    status 2 and print nothing on stdout.
```console
    Runs each `$ COMMAND` line with bash and shows the commands, each followed by what
    it printed. `$ echo $?` shows the exit status of the command before it.
```python run
    Runs the code and shows it as a ```python block. It must be followed by an empty
    ```output block, which becomes a ```text block holding what the code printed.
```python markdown
    Runs the code and puts what it printed in the page, as Markdown (a table, say); the
    code itself is not shown.

The output file is written even when an example misbehaves (a check with the wrong exit
status, a Python error, an internal error or traceback from smol-dsl); each such problem
is listed and the script exits with status 1.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE / "language.md.in"
DEFAULT_OUTPUT = HERE.parent / "language.md"
COMMAND_SECONDS = 300
FENCE = re.compile(r"^(\s*)```(\w+)(.*)$")


@dataclass
class Builder:
    """Expands the template's directive blocks by running them in `workdir`."""

    workdir: Path
    env: dict[str, str]
    last_file: str | None = None
    checks: int = 0
    problems: list[str] = field(default_factory=list)

    def shell(self, command: str) -> tuple[int, str, str]:
        """Run `command` with bash in the work directory: (exit status, stdout, stderr)."""
        try:
            done = subprocess.run(
                ["bash", "-c", command],
                cwd=self.workdir,
                env=self.env,
                capture_output=True,
                text=True,
                timeout=COMMAND_SECONDS,
            )
        except subprocess.TimeoutExpired:
            self.problems.append(f"timed out after {COMMAND_SECONDS} s: {command}")
            return 124, "", f"(timed out after {COMMAND_SECONDS} s)"
        return done.returncode, done.stdout, done.stderr

    def note_crash(self, what: str, text: str) -> None:
        if "internal error" in text or "Traceback" in text:
            self.problems.append(f"{what}: {text[-600:]}")

    def sched(self, body: list[str], attrs: list[str]) -> list[str]:
        name = next(a.removeprefix("file=") for a in attrs if a.startswith("file="))
        text = "\n".join(body) + ("" if "nonl" in attrs else "\n")
        (self.workdir / name).write_text(text, encoding="utf-8")
        self.last_file = name
        return ["```sched", *body, "```"]

    def check(self, attrs: list[str]) -> list[str]:
        if self.last_file is None:
            raise SystemExit("a ```check block comes before any ```sched file= block")
        self.checks += 1
        want = 0 if "ok" in attrs else 2
        status, out, err = self.shell(f"smol-dsl check {self.last_file}")
        text = (out + err).rstrip("\n")
        if status != want or (want == 2 and out):
            self.problems.append(f"check {self.last_file}: exit status {status} (wanted {want}), stdout {out!r}")
        self.note_crash(f"check {self.last_file}", text)
        return ["```text", *text.split("\n"), "```"]

    def console(self, body: list[str]) -> list[str]:
        shown, status = [], 0
        for line in body:
            if not line.startswith("$ "):
                continue
            command = line[2:]
            shown.append(line)
            if command.strip() == "echo $?":
                shown.append(str(status))
                continue
            status, out, err = self.shell(command)
            text = (out + err).rstrip("\n")
            if text:
                shown += text.split("\n")
            self.note_crash(f"console {command}", text)
        return ["```console", *shown, "```"]

    def python(self, body: list[str]) -> list[str]:
        script = self.workdir / "snippet.py"
        script.write_text("\n".join(body) + "\n", encoding="utf-8")
        status, out, err = self.shell("python snippet.py")
        if status != 0:
            self.problems.append(f"python example failed: {err[-1500:]}")
        return ["```text", *(out + err).rstrip("\n").split("\n"), "```"]

    def expand(self, lines: list[str]) -> list[str]:
        """The template's lines with every directive block replaced by its real output."""
        out: list[str] = []
        i = 0
        while i < len(lines):
            match = FENCE.match(lines[i])
            if not match:
                out.append(lines[i])
                i += 1
                continue
            indent, lang, attrs = match.group(1), match.group(2), match.group(3).split()
            body, i = block(lines, i)
            if lang == "sched" and any(a.startswith("file=") for a in attrs):
                new = self.sched(body, attrs)
            elif lang == "check":
                new = self.check(attrs)
            elif lang == "console":
                new = self.console(body)
            elif lang == "python" and "markdown" in attrs:
                new = self.python(body)[1:-1]  # unfenced
            elif lang == "python" and "run" in attrs:
                new = ["```python", *body, "```"]
                while not lines[i].strip():  # the blank lines before ```output
                    new.append("")
                    i += 1
                if lines[i].strip() != "```output":
                    raise SystemExit(f"line {i + 1}: a ```python run block must be followed by ```output")
                _, i = block(lines, i)
                new += self.python(body)
            else:
                new = [f"```{lang}{match.group(3)}", *body, "```"]
            out += [indent + line if line else line for line in new]
        return out


def block(lines: list[str], start: int) -> tuple[list[str], int]:
    """The body of the fenced block opening at `start`, unindented, and the index after it."""
    indent = re.match(r"^(\s*)", lines[start]).group(1)
    end = start + 1
    while end < len(lines) and lines[end] != indent + "```":
        end += 1
    if end == len(lines):
        raise SystemExit(f"line {start + 1}: the fenced block is never closed")
    return [line[len(indent) :] for line in lines[start + 1 : end]], end + 1


def tool_env(bin_dir: Path) -> dict[str, str]:
    """An environment whose `python` is this interpreter and whose `smol-dsl` always works."""
    # wrapper scripts, not symlinks: a symlinked venv python would not find its venv
    commands = {"python": ""}
    if shutil.which("smol-dsl") is None:
        commands["smol-dsl"] = " -m smol_dsl.cli"
    for name, module in commands.items():
        wrapper = bin_dir / name
        wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}"{module} "$@"\n', encoding="utf-8")
        wrapper.chmod(0o755)
    env = dict(os.environ, PYTHONWARNINGS="ignore", JAX_PLATFORMS="cpu")
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env.pop("SMOL_DSL_DEBUG", None)
    return env


def main(argv: list[str]) -> int:
    output = Path(argv[1]) if len(argv) > 1 else DEFAULT_OUTPUT
    lines = TEMPLATE.read_text(encoding="utf-8").split("\n")
    with tempfile.TemporaryDirectory(prefix="smol-dsl-docs-") as temp:
        bin_dir, workdir = Path(temp, "bin"), Path(temp, "run")
        bin_dir.mkdir()
        workdir.mkdir()
        builder = Builder(workdir, tool_env(bin_dir))
        text = "\n".join(builder.expand(lines))
    output.write_text(text, encoding="utf-8")
    print(f"wrote {output} ({builder.checks} checks)")
    for problem in builder.problems:
        print("PROBLEM:", problem, file=sys.stderr)
    return 1 if builder.problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
