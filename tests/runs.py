"""What the application tests share: running a page's documented example or a workload file, and a command
line that must refuse its input in one line."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

from pipeline_sim.cli import main

DOCS = Path(__file__).resolve().parent.parent / "docs"


def run_doc_example(page: str) -> tuple[dict, str]:
    """Run the one Python example of ``docs/<page>`` as written; return its global names and what it printed."""
    doc = DOCS / page
    (block,) = re.findall(r"```python\n(.*?)```", doc.read_text(), flags=re.S)
    scope: dict = {"__name__": f"{doc.stem}_example"}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(block, str(doc), "exec"), scope)
    return scope, printed.getvalue()


def ran_file(tmp_path: Path, text: str) -> tuple[Path, dict]:
    """Write a workload file of ``text`` and ``run`` it into a new folder: (the folder, its results.json, read as
    strict JSON)."""
    path = tmp_path / "workload.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    return out, json.loads((out / "results.json").read_text(), parse_constant=_not_json)


def _not_json(constant: str):
    raise AssertionError(f"results.json holds {constant}, which strict JSON has not")


def refused_file(tmp_path: Path, capsys, kind: str, text: str, *argv: str) -> str:
    """Write a ``kind`` workload file of ``text`` and :func:`refused` its ``run`` (or the command ``argv``
    names, the file after it); the one line."""
    path = tmp_path / "bad.toml"
    path.write_text(f'kind = "{kind}"\n{text}\n')
    command = list(argv) or ["run"]
    return refused([command[0], str(path), *command[1:], *([] if argv else ["--out", str(tmp_path / "o")])], capsys)


def refused(argv: list[str], capsys) -> str:
    """Run the command line ``argv``, which must refuse its input: exit status 2 and one line on stderr with
    no traceback; that line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err
