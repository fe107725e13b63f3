"""The repository explains itself: nothing in it points outside it.

Every tracked text file is free of references to documents that exist only
outside the repository (a sibling ``shared`` folder, its pipeline notes, its
numbered paper files), since papers are cited by the keys of
docs/bibliography.md and the domain by docs/pipeline.md sections; and every
relative link of the Markdown documentation resolves to a file of the
repository, and every anchor to a heading or an ``id`` of its target.
"""

import dataclasses
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# written so that this file does not match them itself
FORBIDDEN = {
    "the sibling shared folder": re.compile(r"\.\./shared|shared/seed[s]"),
    "the pipeline notes outside the repository": re.compile(r"\bPIPELIN[E](?:\.md)?\b"),
    "a numbered paper file (cite the bibliography key)": re.compile(r"(?<![\w.,])00\d(?![\w.]|,\d)"),
}
SKIP_DIRS = {".git", ".venv", "__pycache__", ".pytest_cache", ".hypothesis", "runs", "bench-results"}


def tracked_files(root: Path) -> list[Path]:
    """The files git tracks; every file but caches and outputs outside a git checkout."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
        return [root / name for name in out.decode().split("\0") if name]
    except (OSError, subprocess.CalledProcessError):
        return [p for p in root.rglob("*") if p.is_file() and not SKIP_DIRS & set(p.relative_to(root).parts)]


def text_of(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
        return None


def test_no_file_points_outside_the_repository(root):
    found = []
    for path in tracked_files(root):
        text = text_of(path)
        if text is None:
            continue
        for lineno, line in enumerate(text.splitlines(), 1):
            found += [f"{path.relative_to(root)}:{lineno}: {what}: {line.strip()[:100]}"
                      for what, pattern in FORBIDDEN.items() if pattern.search(line)]
    assert not found, "\n".join(found)


def doc_files(root: Path) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def without_code(text: str) -> str:
    """The Markdown without fenced code blocks and inline code spans."""
    text = re.sub(r"^(```|~~~).*?^\1", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"^(```|~~~).*?^\1", "", path.read_text(), flags=re.S | re.M)
    seen: dict[str, int] = {}
    out = set(re.findall(r"""\bid=["']([^"']+)["']""", text))
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, flags=re.M):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(path: Path) -> list[str]:
    """Targets of the inline links and images of a Markdown file, and of its HTML href/src."""
    text = without_code(path.read_text())
    return (re.findall(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)", text)
            + re.findall(r"""\b(?:href|src)=["']([^"']+)["']""", text))


def test_link_parser_finds_links_and_anchors(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# A `b` title, 2.1\n\n## Same\n## Same\n<a id=\"x\"></a>\n"
                    "[one](other.md#same-1) ![img](i.png) `[not](code.md)`\n```\n[no](fence.md)\n# not a heading\n```\n")
    assert links(page) == ["other.md#same-1", "i.png"]
    assert anchors(page) == {"a-b-title-21", "same", "same-1", "x"}


def relative_links() -> list[tuple[str, str]]:
    return [(p.relative_to(ROOT).as_posix(), target) for p in doc_files(ROOT) for target in links(p)
            if not re.match(r"[a-z][a-z0-9+.-]*:", target, flags=re.I)]


def test_documentation_has_relative_links():
    assert len(relative_links()) >= 20


@pytest.mark.parametrize("source,target", relative_links())
def test_relative_link_resolves(root, source, target):
    path_part, _, anchor = target.partition("#")
    base = (root / source).parent
    dest = (base / path_part).resolve() if path_part else (root / source).resolve()
    assert dest.is_relative_to(root.resolve()), f"{source}: {target} points outside the repository"
    assert dest.exists(), f"{source}: {target} does not exist"
    if anchor:
        assert dest.suffix == ".md", f"{source}: {target}: anchor into a non-Markdown file"
        assert anchor in anchors(dest), f"{source}: {target}: no heading or id '{anchor}' in {dest.name}"


def test_readme_links_the_documentation(root):
    targets = [t.partition("#")[0] for t in links(root / "README.md")]
    assert "docs/README.md" in targets
    assert all((root / "docs" / name).exists() for name in ("README.md", "bibliography.md", "pipeline.md"))


def test_generated_docs_are_current(root):
    """The settings tables and the counter glossary are what the declarations give now (`make docs`)."""
    from pipeline_sim import docgen

    assert docgen.stale(root) == [], "run `make docs`"


def test_a_stale_generated_block_is_caught(root, tmp_path):
    """Drop one row of a generated table in a copy of the docs: the check names that file."""
    from pipeline_sim import docgen

    for f in docgen.BLOCKS:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text((root / f).read_text())
    page = tmp_path / "docs/scene-format.md"
    page.write_text("\n".join(line for line in page.read_text().splitlines() if not line.startswith("| `pass.blend`"))
                    + "\n")
    assert docgen.stale(tmp_path) == ["docs/scene-format.md"]


def test_the_counter_glossary_lists_what_a_run_counts(root):
    """Every (unit, counter) row of a real run's counters table, with its timing_dependent flag, is a row of
    docs/counters.md, and nothing else is."""
    from pipeline_sim import load_arch, load_scene, render_scene

    scene = load_scene(root / "workloads/scenes/default.toml")
    scene = scene.replace(image=dataclasses.replace(scene.image, width=32, height=18, spp=1))
    counters = render_scene(scene, load_arch()).counters
    ran = {(r.unit, r.counter, "yes" if r.timing_dependent else "no") for r in counters.itertuples()}
    text = (root / "docs/counters.md").read_text()
    rows = {tuple(c.strip(" `") for c in (line.split("|")[1], line.split("|")[2], line.split("|")[4]))
            for line in text.splitlines() if line.startswith("| `")}
    assert rows == ran
