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
    marker = json.loads((target / MARKER).read_text())
    st = (target / "x.csv").stat()
    assert marker == {"written_by": "pipeline-sim", "kind": "run", "files": {"x.csv": [st.st_size, st.st_mtime_ns]},
                      "folders": []}


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


HOLD_LOCK = """
import os, sys, time
from pipeline_sim.output_folder import hold_lock
os.mkdir(sys.argv[1])
fd = os.open(sys.argv[1], os.O_RDONLY)
hold_lock(fd)
print("locked", flush=True)
time.sleep(600)
"""


def test_leftovers_of_killed_writers_are_cleaned_and_live_ones_kept(tmp_path, root):
    """A live writer (another process holding its staging folder locked) keeps it; a killed one's goes."""
    dead = _dead_pid()
    killed = tmp_path / f".o.pipeline-sim-{dead}-abc_1.tmp"
    killed.mkdir()
    (killed / "image.npy").write_text("half")
    own_past_life = tmp_path / f".o.pipeline-sim-{os.getpid()}-abc_4.tmp"   # a container's tool is always pid 1
    own_past_life.mkdir()
    killed_file = tmp_path / f".points.csv.pipeline-sim-{dead}-abc_5.tmp"
    killed_file.write_text("half")
    unrelated = tmp_path / ".o.keep.tmp"
    unrelated.mkdir()
    writer = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(tmp_path / ".o.pipeline-sim-1-abc_2.tmp")],
                              stdout=subprocess.PIPE, text=True, cwd=root, env={**os.environ, "PYTHONPATH": str(root)})
    try:
        assert writer.stdout.readline().strip() == "locked"
        live = tmp_path / ".o.pipeline-sim-1-abc_2.tmp"
        with OutputFolder(tmp_path / "o", "run") as out:
            _write_outputs(out, {"x.csv": "1"})
        assert not killed.exists() and not own_past_life.exists() and not killed_file.exists()
        assert live.is_dir() and unrelated.is_dir()
    finally:
        writer.kill()
        writer.wait()
    # unlocked now, but named for a live process (pid 1) and young: perhaps a writer that has not locked it yet
    assert clean_leftovers(tmp_path) == [] and live.is_dir()
    os.utime(live, (0, 0))
    assert clean_leftovers(tmp_path) == [live]


def test_outputs_set_aside_by_a_killed_replacement_come_back(tmp_path):
    """Killed between moving the old outputs aside and moving the new ones in: the old ones are restored."""
    aside = tmp_path / f".o.pipeline-sim-{_dead_pid()}-abc_1.old"
    aside.mkdir()
    (aside / "previous").mkdir()
    (aside / "previous" / "x.csv").write_text("previous run")
    assert clean_leftovers(tmp_path) == [aside]
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
    import re

    mine, theirs = tmp_path / "mine.html", tmp_path / "theirs.html"
    mine.write_text('<html><head><meta name="generator" content="pipeline-sim">')
    theirs.write_text("<html>notes")
    sig = (re.compile(r'<html><head><meta name="generator" content="pipeline-sim">'),)
    check_output_file(mine, sig, force=False, option="-o")
    with pytest.raises(UserError, match="not written by pipeline-sim"):
        check_output_file(theirs, sig, force=False, option="-o")
    check_output_file(theirs, sig, force=True, option="-o")
    with pytest.raises(UserError, match="is a folder"):
        check_output_file(tmp_path, sig, force=True, option="-o")


# ---------------------------------------------------------------------------
# the rules as a model, over random folder states

NAMES = ["a.csv", "b.csv", "figs/c.png", "figs/d.png", "notes.txt", "figs/notes.txt"]


def _marker_for(target: Path, listed: list[str], changed: list[str]) -> str:
    """A marker vouching for ``listed`` as they are now (or, for ``changed``, as they were before an edit)."""
    files = {}
    for rel in listed:
        p = target / rel
        if p.is_file():
            st = p.stat()
            files[rel] = [st.st_size + (1 if rel in changed else 0), st.st_mtime_ns]
        else:
            files[rel] = [1, 1]
    folders = sorted({str(Path(r).parent) for r in listed if "/" in r})
    return json.dumps({"written_by": "pipeline-sim", "kind": "run", "files": files, "folders": folders})


@st.composite
def folder_states(draw):
    existing = draw(st.lists(st.sampled_from(NAMES), unique=True))
    marked = draw(st.booleans())
    listed = draw(st.lists(st.sampled_from(NAMES), unique=True)) if marked else []
    changed = draw(st.lists(st.sampled_from(existing), unique=True)) if existing else []
    written = draw(st.lists(st.sampled_from(NAMES[:4]), unique=True))
    return existing, marked, listed, changed, written, draw(st.booleans()), draw(st.booleans())


@settings(max_examples=200)
@given(folder_states())
def test_never_touches_what_it_did_not_write(tmp_path_factory, state):
    """Whatever the folder holds (at any depth), the tool's marker, edits since, --force, or a failure:
    a file the marker does not vouch for is never changed or removed, unless the tool writes that very path
    when forced; and the tool's own unchanged earlier files that it does not write again are removed."""
    existing, marked, listed, changed, written, force, fail = state
    root = tmp_path_factory.mktemp("model")
    target = root / "out"
    target.mkdir()
    for rel in existing:
        (target / rel).parent.mkdir(exist_ok=True)
        (target / rel).write_text(f"user {rel}")
    if marked:
        (target / MARKER).write_text(_marker_for(target, listed, changed))
    before = _snapshot(root)
    ours = {r for r in existing if r in listed and r not in changed}
    foreign = [r for r in existing if r not in ours]
    if marked and "figs" in {str(Path(r).parent) for r in listed}:
        pass
    elif any(r.startswith("figs/") for r in existing):
        foreign.append("figs")       # a folder the marker does not list is the user's
    try:
        with OutputFolder(target, "run", force=force) as out:
            for rel in written:
                (out.staging / rel).parent.mkdir(exist_ok=True)
                (out.staging / rel).write_text(f"new {rel}")
            if fail:
                raise RuntimeError
            out.commit()
    except UserError:
        assert foreign and not force          # refused exactly when a foreign entry is there and not forced
        assert _snapshot(root) == before
        return
    except RuntimeError:
        assert _snapshot(root) == before      # a failed job changes nothing
        assert sorted(p.name for p in root.iterdir()) == ["out"]
        return
    assert not foreign or force
    after = _snapshot(root)
    for rel in existing:
        key = f"out/{rel}"
        if rel in written:
            assert after[key] == f"new {rel}"
        elif rel in ours:
            assert key not in after           # the tool's own stale output: gone
        else:
            assert after[key] == before[key]  # the user's and not rewritten: untouched
    for rel in written:
        assert after[f"out/{rel}"] == f"new {rel}"
    assert sorted(json.loads(after[f"out/{MARKER}"])["files"]) == sorted(written)
    assert sorted(p.name for p in root.iterdir()) == ["out"]   # nothing hidden left beside it
    assert not [p for p in target.rglob(".*") if p.name != MARKER]


def test_staging_names_carry_the_pid():
    assert staging_prefix("out") == f".out.pipeline-sim-{os.getpid()}-"


@pytest.mark.parametrize("names", [[".."], ["."], ["../victim"], ["/abs/path"], ["a/../../x"], [MARKER]])
def test_a_marker_naming_anything_outside_its_folder_is_not_the_tools(tmp_path, monkeypatch, names):
    """A crafted or corrupted marker cannot make the tool remove anything: the folder is then simply foreign."""
    work = tmp_path / "work"
    work.mkdir()
    (tmp_path / "victim").write_text("outside")
    (work / "notes.txt").write_text("mine")
    (work / MARKER).write_text(json.dumps({"written_by": "pipeline-sim", "kind": "run", "folders": [],
                                           "files": {n: [1, 1] for n in names}}))
    monkeypatch.chdir(work)
    with pytest.raises(UserError, match="not written by pipeline-sim"):
        OutputFolder(".", "run")
    with OutputFolder(".", "run", force=True) as out:
        _write_outputs(out, {"x.csv": "1"})
    assert (tmp_path / "victim").read_text() == "outside" and (work / "notes.txt").read_text() == "mine"


def test_a_file_added_while_the_job_runs_is_kept(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "1", "stale.csv": "s"})
    with OutputFolder(tmp_path / "o", "run") as out:       # claimed: the folder is the tool's
        (tmp_path / "o" / "notes.txt").write_text("written during the run")
        (tmp_path / "o" / "x.csv").write_text("edited during the run")
        _write_outputs(out, {"x.csv": "2"})
    assert (tmp_path / "o" / "notes.txt").read_text() == "written during the run"
    assert (tmp_path / "o" / "x.csv").read_text() == "2"      # the output of the same name lands
    assert not (tmp_path / "o" / "stale.csv").exists()        # the tool's own, unchanged: removed
    # a folder that did not exist at the claim but does at the commit, with a file in it
    with OutputFolder(tmp_path / "p", "run") as out:
        (tmp_path / "p").mkdir()
        (tmp_path / "p" / "notes.txt").write_text("mine")
        _write_outputs(out, {"x.csv": "1"})
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == [MARKER, "notes.txt", "x.csv"]


def test_a_file_inside_the_tools_subfolder_is_kept(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        (out.staging / "report_files").mkdir()
        (out.staging / "report_files" / "a.png").write_text("a")
        out.commit()
    (tmp_path / "o" / "report_files" / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="report_files/notes.txt"):
        OutputFolder(tmp_path / "o", "run")
    (tmp_path / "o" / "report_files" / "notes.txt").unlink()
    (tmp_path / "o" / "report_files" / "a.png").write_text("annotated by hand")   # an edited output is the user's
    with pytest.raises(UserError, match="report_files/a.png"):
        OutputFolder(tmp_path / "o", "run")


def test_another_kind_of_output_is_refused_unless_forced(tmp_path):
    with OutputFolder(tmp_path / "o", "sweep point") as out:
        _write_outputs(out, {"run.json": "{}"})
    with pytest.raises(UserError, match="outputs of a sweep point"):
        OutputFolder(tmp_path / "o", "run")
    with OutputFolder(tmp_path / "o", "run", force=True) as out:
        _write_outputs(out, {"run.json": "[]"})
    assert (tmp_path / "o" / "run.json").read_text() == "[]"


def test_a_replaced_folder_keeps_its_mode_and_a_setgid_parent_its_group_bit(tmp_path):
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    os.chmod(tmp_path / "o", 0o700)
    with OutputFolder(tmp_path / "o", "run") as out:
        _write_outputs(out, {"x.csv": "2"})
    assert stat.S_IMODE((tmp_path / "o").stat().st_mode) == 0o700
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o2775)
    with OutputFolder(shared / "run", "run") as out:
        _write_outputs(out, {"x.csv": "1"})
    assert (shared / "run").stat().st_mode & stat.S_ISGID


def test_a_folder_that_cannot_be_swapped_is_written_in_place(tmp_path, monkeypatch):
    """A mount point (or a folder on another file system) cannot be renamed away: the outputs go in."""
    import pipeline_sim.output_folder as of

    target = tmp_path / "mnt"
    with OutputFolder(target, "run") as out:
        _write_outputs(out, {"x.csv": "1", "stale.csv": "s"})
    monkeypatch.setattr(of.os.path, "ismount", lambda p: Path(p) == target)
    out = OutputFolder(target, "run")
    assert out.merge and out.staging.parent == target
    with out:
        _write_outputs(out, {"x.csv": "2"})
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "x.csv"] and (target / "x.csv").read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["mnt"]


def test_a_killed_sweep_points_set_aside_outputs_come_back(tmp_path):
    points = tmp_path / "points"
    aside = points / f".ab12.pipeline-sim-{_dead_pid()}-x_1.old"
    (aside / "previous").mkdir(parents=True)
    (aside / "previous" / "run.json").write_text("{}")
    clean_leftovers(points)
    assert _snapshot(tmp_path) == {"points/ab12/run.json": "{}"}
