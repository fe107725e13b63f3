"""Output locations: what is refused, what is replaced, what is kept, leftovers of killed writes, file modes.

The rules are checked against a plain model of them (which names may
change), over random folder states, not against the module's own output.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.errors import UserError
from pipeline_sim.output import atomic_write_text
from pipeline_sim.output_folder import MARKER, OutputFolder, check_output_file, clean_leftovers, staging_prefix


def _write_outputs(folder: OutputFolder, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (folder.staging / name).write_text(text)
    return folder.commit()


def _snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` (relative path -> content)."""
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_new_folder_is_created_with_a_marker(tmp_path):
    with OutputFolder(tmp_path / "a" / "b", "run") as out:
        target = _write_outputs(out, {"x.csv": "1"})
    assert _snapshot(tmp_path) == {"a/b/x.csv": "1", f"a/b/{MARKER}": (target / MARKER).read_text()}
    assert json.loads((target / MARKER).read_text()) == {"written_by": "pipeline-sim", "kind": "run",
                                                          "files": ["x.csv"]}


def test_own_folder_is_replaced_whole(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"old.csv": "old", "x.csv": "1"})
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "2"})
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [MARKER, "x.csv"]
    assert (tmp_path / "o" / "x.csv").read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["o"]   # nothing hidden left beside it


def test_a_failed_job_leaves_the_previous_outputs(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    before = _snapshot(tmp_path)
    with pytest.raises(RuntimeError):
        with OutputFolder(tmp_path / "o", "run") as out:
            (out.staging / "x.csv").write_text("half")
            raise RuntimeError("simulation failed")
    assert _snapshot(tmp_path) == before and [p.name for p in tmp_path.iterdir()] == ["o"]


def test_a_regular_file_is_refused_even_when_forced(tmp_path):
    (tmp_path / "some_file").write_text("data")
    for force in (False, True):
        with pytest.raises(UserError, match="not a folder"):
            OutputFolder(tmp_path / "some_file", "run", force=force)
    assert _snapshot(tmp_path) == {"some_file": "data"} and len(list(tmp_path.iterdir())) == 1


def test_a_foreign_folder_is_refused_unless_forced(tmp_path):
    d = tmp_path / "mydir"
    d.mkdir()
    (d / "thesis.txt").write_text("years of work")
    (d / "x.csv").write_text("mine too")
    with pytest.raises(UserError, match="was not written by pipeline-sim.*thesis.txt"):
        OutputFolder(d, "run")
    assert _snapshot(tmp_path) == {"mydir/thesis.txt": "years of work", "mydir/x.csv": "mine too"}
    with OutputFolder(d, "run", force=True) as out:
        _write_outputs(out, {"x.csv": "1", "y.csv": "2"})
    assert (d / "thesis.txt").read_text() == "years of work" and (d / "x.csv").read_text() == "1"
    # still not wholly the tool's: refused again without --force
    with pytest.raises(UserError, match="holds files pipeline-sim did not write.*thesis.txt"):
        OutputFolder(d, "run")
    # forced again, the tool removes its own stale output (y.csv) but nothing else
    with OutputFolder(d, "run", force=True) as out:
        _write_outputs(out, {"x.csv": "3"})
    assert sorted(p.name for p in d.iterdir()) == [MARKER, "thesis.txt", "x.csv"]


def test_an_empty_folder_is_used(tmp_path):
    (tmp_path / "e").mkdir()
    with OutputFolder(tmp_path / "e", "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    assert sorted(p.name for p in (tmp_path / "e").iterdir()) == [MARKER, "x.csv"]


def test_the_working_directory_is_written_in_place(tmp_path, monkeypatch):
    """`--out .`: the folder cannot be swapped; a folder of the tool's is rewritten in place, nothing beside it."""
    work = tmp_path / "work"
    with OutputFolder(work, "run") as out:
        _write_outputs(out, {"x.csv": "1", "stale.csv": "s"})
    monkeypatch.chdir(work)
    with OutputFolder(".", "run") as out:
        _write_outputs(out, {"x.csv": "2"})
    assert sorted(p.name for p in work.iterdir()) == [MARKER, "x.csv"] and (work / "x.csv").read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["work"]
    (work / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="notes.txt"):
        OutputFolder(".", "run")
    assert [p.name for p in tmp_path.iterdir()] == ["work"] and (work / "notes.txt").exists()


def test_a_link_to_a_folder_is_written_through(tmp_path):
    real = tmp_path / "real"
    with OutputFolder(real, "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    (tmp_path / "link").symlink_to(real)
    with OutputFolder(tmp_path / "link", "run") as out:
        _write_outputs(out, {"x.csv": "2"})
    assert (tmp_path / "link").is_symlink() and (real / "x.csv").read_text() == "2"


def test_subfolders_are_replaced(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        (out.staging / "figs").mkdir()
        (out.staging / "figs" / "a.png").write_text("a")
        out.commit()
    (tmp_path / "o" / "keep.txt").write_text("k")
    with OutputFolder(tmp_path / "o", "run", force=True) as out:
        (out.staging / "figs").mkdir()
        (out.staging / "figs" / "b.png").write_text("b")
        out.commit()
    assert _snapshot(tmp_path / "o") == {"figs/b.png": "b", "keep.txt": "k",
                                         MARKER: (tmp_path / "o" / MARKER).read_text()}


def test_unwritable_location_fails_before_the_work(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="cannot write"):
        OutputFolder(tmp_path / "file" / "out", "run")   # a path through a file can never be written
    assert _snapshot(tmp_path) == {"file": "x"}


def test_leftovers_of_dead_processes_are_cleaned_and_live_ones_kept(tmp_path):
    dead, live = _dead_pid(), os.getpid()
    killed = tmp_path / f".o.pipeline-sim-{dead}-abc_1.tmp"
    killed.mkdir()
    (killed / "image.npy").write_text("half")
    running = tmp_path / f".o.pipeline-sim-{live}-abc_2.tmp"
    running.mkdir()
    other = tmp_path / f".other.pipeline-sim-{dead}-abc_3.tmp"   # another target's: not ours to judge here
    other.mkdir()
    unrelated = tmp_path / ".o.keep.tmp"
    unrelated.mkdir()
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    assert not killed.exists() and running.is_dir() and other.is_dir() and unrelated.is_dir()


def test_outputs_set_aside_by_a_killed_replacement_come_back(tmp_path):
    """Killed between moving the old outputs aside and moving the new ones in: the old ones are restored."""
    aside = tmp_path / f".o.pipeline-sim-{_dead_pid()}-abc_1.old"
    aside.mkdir()
    (aside / "previous").mkdir()
    (aside / "previous" / "x.csv").write_text("previous run")
    assert clean_leftovers(tmp_path, "o") == [aside]
    assert _snapshot(tmp_path) == {"o/x.csv": "previous run"}


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_modes_follow_the_umask(tmp_path, mask):
    old = os.umask(mask)
    try:
        with OutputFolder(tmp_path / "o", "run") as out:
            (out.staging / "sub").mkdir()
            atomic_write_text(out.staging / "sub" / "fig.png", "png")
            atomic_write_text(out.staging / "points.csv", "a,b")
            out.commit()
    finally:
        os.umask(old)
    mode = lambda p: stat.S_IMODE(p.stat().st_mode)  # noqa: E731
    assert mode(tmp_path / "o") == 0o777 & ~mask
    assert mode(tmp_path / "o" / "sub") == 0o777 & ~mask
    for f in ("points.csv", "sub/fig.png", MARKER):
        assert mode(tmp_path / "o" / f) == 0o666 & ~mask, f


def test_atomic_write_keeps_an_existing_files_mode(tmp_path):
    p = tmp_path / "points.csv"
    p.write_text("old")
    p.chmod(0o640)
    atomic_write_text(p, "new")
    assert stat.S_IMODE(p.stat().st_mode) == 0o640 and p.read_text() == "new"


def test_output_file_check(tmp_path):
    mine, theirs = tmp_path / "mine.html", tmp_path / "theirs.html"
    mine.write_text('<html><head><meta name="generator" content="pipeline-sim">')
    theirs.write_text("<html>notes")
    sig = ('<meta name="generator" content="pipeline-sim">',)
    check_output_file(mine, sig, force=False, option="-o")
    with pytest.raises(UserError, match="not written by pipeline-sim"):
        check_output_file(theirs, sig, force=False, option="-o")
    check_output_file(theirs, sig, force=True, option="-o")
    with pytest.raises(UserError, match="is a folder"):
        check_output_file(tmp_path, sig, force=True, option="-o")


# ---------------------------------------------------------------------------
# the rules as a model, over random folder states

NAMES = ["a.csv", "b.csv", "c.png", "notes.txt", "sub"]


@st.composite
def folder_states(draw):
    existing = draw(st.lists(st.sampled_from(NAMES), unique=True))
    marked = draw(st.booleans())
    listed = draw(st.lists(st.sampled_from(NAMES), unique=True)) if marked else []
    written = draw(st.lists(st.sampled_from(NAMES[:3]), unique=True))
    return existing, marked, listed, written, draw(st.booleans()), draw(st.booleans())


@settings(max_examples=150)
@given(folder_states())
def test_never_touches_what_it_did_not_write(tmp_path_factory, state):
    existing, marked, listed, written, force, fail = state
    root = tmp_path_factory.mktemp("model")
    target = root / "out"
    target.mkdir()
    for name in existing:
        (target / name).write_text(f"user {name}")
    if marked:
        (target / MARKER).write_text(json.dumps({"written_by": "pipeline-sim", "kind": "run", "files": listed}))
    before = _snapshot(root)
    foreign = [n for n in existing if n not in listed]
    try:
        with OutputFolder(target, "run", force=force) as out:
            for name in written:
                (out.staging / name).write_text(f"new {name}")
            if fail:
                raise RuntimeError
            out.commit()
    except UserError:
        assert foreign and not force          # refused exactly when a foreign name is there and not forced
        assert _snapshot(root) == before
        return
    except RuntimeError:
        assert _snapshot(root) == before      # a failed job changes nothing
        assert sorted(p.name for p in root.iterdir()) == ["out"]
        return
    assert not foreign or force
    after = _snapshot(root)
    for name in existing:
        key = f"out/{name}"
        if name in written:
            assert after[key] == f"new {name}"
        elif name in foreign:
            assert after[key] == before[key]  # foreign and not rewritten: untouched
        else:
            assert key not in after           # the tool's own stale output: gone
    for name in written:
        assert after[f"out/{name}"] == f"new {name}"
    assert json.loads(after[f"out/{MARKER}"])["files"] == sorted(written)
    assert sorted(p.name for p in root.iterdir()) == ["out"]   # nothing hidden left beside it
    assert not [p for p in target.iterdir() if p.name.startswith(".") and p.name != MARKER]


def test_staging_names_carry_the_pid():
    assert staging_prefix("out") == f".out.pipeline-sim-{os.getpid()}-"
