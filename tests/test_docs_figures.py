"""Every figure in README.md and docs/*.md is what the command in its caption draws now.

A figure's caption is the paragraph right after its image (blank lines between them skipped). A
backticked ``doabench plot ...`` or ``doabench compare ... --plot OUT`` in it is the figure's
command; it must write the image the page shows. The command runs in-process, its braces and
globs expanded as bash expands them, with its output sent to a temporary path, and the content
fingerprint in the new PNG (``doabench:content``, :mod:`doabench.reporting.figure_content`) must
equal the one in the committed PNG. The fingerprint depends on what is drawn, not on file names
or the renderer, so renaming the results files a caption names keeps the check passing, while
any change of data, labels or styles fails it, naming the page, the image and the command that
regenerates it.

Commands that read files that are not committed (``runs/...``) cannot be checked here and skip
with that reason; those that need the real LibriSpeech (``--librispeech PATH``) run when it is
found and are slow.
"""
from __future__ import annotations

import glob
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from doabench.cli.main import main
from doabench.reporting.figure_content import png_fingerprint
from doabench.reporting.plots import output_paths

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
IMAGE = re.compile(r"!\[(?P<alt>[^\]]*)\]\((?P<path>[^)\s]+)\)")
#: the placeholder the captions write for the LibriSpeech root
LIBRISPEECH_PLACEHOLDER = "PATH"


@dataclass(frozen=True)
class DocsFigure:
    """An image of a page and the command its caption gives (empty when it gives none)."""

    page: Path
    image: Path
    command: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}: {self.image.relative_to(ROOT)}"


def caption_of(lines: list[str], image_line: int) -> str:
    """The paragraph after line ``image_line`` (blank lines right after the image skipped), one line."""
    i = image_line + 1
    while i < len(lines) and not lines[i].strip():
        i += 1
    paragraph = []
    while i < len(lines) and lines[i].strip() and not IMAGE.search(lines[i]):
        paragraph.append(lines[i].strip())
        i += 1
    return " ".join(paragraph)


def figure_command(caption: str) -> str:
    """The first backticked ``doabench plot`` or ``doabench compare ... --plot`` command of a caption."""
    for span in re.findall(r"`([^`]+)`", caption):
        words = span.split()
        if words[:2] == ["doabench", "plot"] or (words[:2] == ["doabench", "compare"] and "--plot" in words):
            return span.strip()
    return ""


def docs_figures(pages: list[Path] = PAGES) -> list[DocsFigure]:
    figures = []
    for page in pages:
        lines = page.read_text().splitlines()
        in_code = False
        for number, line in enumerate(lines):
            if line.lstrip().startswith("```"):
                in_code = not in_code
            match = None if in_code else IMAGE.search(line)
            if match is None or "://" in match["path"]:
                continue
            image = (page.parent / match["path"]).resolve()
            figures.append(DocsFigure(page, image, figure_command(caption_of(lines, number))))
    return figures


def expand_braces(word: str) -> list[str]:
    """Bash's brace expansion of one word: ``a{b,c}d`` -> ``abd``, ``acd`` (nested too); a brace
    without a comma at its top level stays as it is."""
    depth, start = 0, None
    for i, ch in enumerate(word):
        if ch == "{":
            if depth == 0:
                start = i
            depth += 1
        elif ch == "}" and depth:
            depth -= 1
            if depth == 0 and start is not None:
                inner, parts, level, last = word[start + 1:i], [], 0, 0
                for j, c in enumerate(inner):
                    level += (c == "{") - (c == "}")
                    if c == "," and level == 0:
                        parts.append(inner[last:j])
                        last = j + 1
                if not parts:  # no comma: literal braces, look further on
                    return [word[:i + 1] + rest for rest in expand_braces(word[i + 1:])]
                parts.append(inner[last:])
                return [expanded for part in parts for expanded in expand_braces(word[:start] + part + word[i + 1:])]
    return [word]


def expand_word(word: str, cwd: Path) -> list[str]:
    """Braces, then globs (sorted; a glob that matches nothing stays as it is, as bash leaves it)."""
    out = []
    for braced in expand_braces(word):
        matches = sorted(glob.glob(braced, root_dir=cwd)) if any(c in braced for c in "*?[") else []
        out.extend(matches or [braced])
    return out


def command_argv(command: str, cwd: Path = ROOT) -> list[str]:
    """The arguments bash would pass to ``doabench`` for ``command``, run in ``cwd``."""
    words = shlex.split(command)
    assert words[0] == "doabench", command
    return [expanded for word in words[1:] for expanded in expand_word(word, cwd)]


def output_option(argv: list[str]) -> str:
    return "--plot" if argv[0] == "compare" else "--out"


def with_output(argv: list[str], out: Path) -> list[str]:
    """``argv`` with the figure written to ``out`` instead (``--out`` of ``plot``, ``--plot`` of ``compare``)."""
    option = output_option(argv)
    assert option in argv, f"{' '.join(argv)} has no {option}"
    i = argv.index(option)
    return [*argv[:i + 1], str(out), *argv[i + 2:]]


def uncommitted_inputs(argv: list[str]) -> list[str]:
    """The arguments that name files a checkout does not hold: ``runs/...`` and missing files."""
    option = output_option(argv)
    out = []
    for i, word in enumerate(argv):
        if i and argv[i - 1] == option:
            continue
        if word.startswith("runs/") or (word.endswith(".json") and not (ROOT / word).is_file()):
            out.append(word)
    return out


FIGURES = docs_figures()


def _unique_commands(librispeech: bool) -> list[pytest.param]:
    """One parameter per image and command (a figure shown on two pages is drawn once)."""
    seen: dict[tuple[Path, str], list[DocsFigure]] = {}
    for figure in FIGURES:
        if figure.command and (LIBRISPEECH_PLACEHOLDER in shlex.split(figure.command)) == librispeech:
            seen.setdefault((figure.image, figure.command), []).append(figure)
    return [pytest.param(group, id=f"{group[0].image.name}") for group in seen.values()]


def _check(figures: list[DocsFigure], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
           librispeech: Path | None = None) -> None:
    figure = figures[0]
    argv = command_argv(figure.command)
    if librispeech is not None:
        argv = [str(librispeech) if word == LIBRISPEECH_PLACEHOLDER else word for word in argv]
    missing = uncommitted_inputs(argv)
    if missing:
        pytest.skip(f"not checkable from committed files: the caption command reads {', '.join(missing[:3])}")
    committed = png_fingerprint(figure.image) if figure.image.is_file() else None
    monkeypatch.chdir(ROOT)  # the caption's paths are relative to the repository root
    assert main(with_output(argv, tmp_path / "figure")) == 0, f"{figure.where}: `{figure.command}` failed"
    drawn = png_fingerprint(tmp_path / "figure.png")
    assert drawn, f"`{figure.command}` wrote a PNG without a content fingerprint"
    pages = ", ".join(str(f.page.relative_to(ROOT)) for f in figures)
    assert committed == drawn, (
        f"{figure.image.relative_to(ROOT)} (shown in {pages}) is not what its caption command draws now"
        + ("" if committed else " (the committed PNG carries no content fingerprint)")
        + f"; regenerate it from the repository root with: {figure.command}")


def test_every_docs_figure_has_a_caption_command_that_writes_it() -> None:
    assert FIGURES, "no figures found in the docs"
    problems = []
    commands: dict[Path, set[str]] = {}
    for figure in FIGURES:
        if not figure.command:
            problems.append(f"{figure.where}: the caption gives no `doabench plot` or `doabench compare --plot` "
                            "command")
            continue
        commands.setdefault(figure.image, set()).add(figure.command)
        argv = shlex.split(figure.command)[1:]
        option = output_option(argv)
        out = argv[argv.index(option) + 1] if option in argv[:-1] else None
        if out is None or output_paths(ROOT / out)[0].resolve() != figure.image.with_suffix(".png"):
            problems.append(f"{figure.where}: the caption command writes {out or 'a default name'}, not this image "
                            f"(`{figure.command}`)")
    problems += [f"{image.relative_to(ROOT)} has different caption commands on different pages: {sorted(found)}"
                 for image, found in commands.items() if len(found) > 1]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("figures", _unique_commands(librispeech=False))
def test_a_docs_figure_is_what_its_caption_command_draws(figures: list[DocsFigure], tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    _check(figures, tmp_path, monkeypatch)


@pytest.mark.parametrize("figures", _unique_commands(librispeech=True))
def test_a_docs_figure_drawn_from_librispeech_is_what_its_caption_command_draws(
        figures: list[DocsFigure], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, librispeech_root: Path) -> None:
    _check(figures, tmp_path, monkeypatch, librispeech=librispeech_root)


def test_a_caption_command_that_draws_another_figure_fails_the_check(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """One results file less in the caption's command: another figure, another fingerprint, and
    the check names the image and the command."""
    figure = next(f for f in FIGURES if f.image.name == "fig6-rmsae-nonsilent-vs-t60.png" and f.command)
    argv = command_argv(figure.command)
    inputs = [w for w in argv if w.endswith(".json")]
    fewer = DocsFigure(figure.page, figure.image, shlex.join(["doabench", *[w for w in argv if w != inputs[-1]]]))
    with pytest.raises(AssertionError) as failure:
        _check([fewer], tmp_path, monkeypatch)
    message = str(failure.value)
    assert "fig6-rmsae-nonsilent-vs-t60.png" in message and "is not what its caption command draws now" in message
    assert fewer.command in message


def test_renamed_input_files_draw_the_same_figure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fingerprint follows what is drawn, not the names of the files it is drawn from."""
    figure = next(f for f in FIGURES if f.image.name == "moving-rmsae-vs-speed.png" and f.command)
    argv = command_argv(figure.command)
    renamed = []
    for k, word in enumerate(argv):
        if word.endswith(".json"):
            copy = tmp_path / f"renamed-{k}.json"
            copy.write_bytes((ROOT / word).read_bytes())
            word = str(copy)
        renamed.append(word)
    monkeypatch.chdir(ROOT)
    assert main(with_output(renamed, tmp_path / "renamed")) == 0
    assert png_fingerprint(tmp_path / "renamed.png") == png_fingerprint(figure.image)


def test_captions_are_read_and_expanded_as_bash_reads_them(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("text\n\n![a figure](img/a.png)\n\n`doabench plot rmsae-vs-t60 r/{x,y_*}.json\n--out docs/img/a`"
                    " (a caption)\nstill the caption\n\n`doabench plot other` is not a caption\n\n"
                    "```\n![in a code block](img/b.png)\n```\n")
    (tmp_path / "r").mkdir()
    for name in ("x.json", "y_2.json", "y_1.json", "z.json"):
        (tmp_path / "r" / name).write_text("{}")
    [figure] = docs_figures([page])
    assert figure.image == tmp_path / "img" / "a.png"
    assert figure.command == "doabench plot rmsae-vs-t60 r/{x,y_*}.json --out docs/img/a"
    assert command_argv(figure.command, tmp_path) == ["plot", "rmsae-vs-t60", "r/x.json", "r/y_1.json", "r/y_2.json",
                                                      "--out", "docs/img/a"]
    assert expand_braces("a{b,c{d,e}}f") == ["abf", "acdf", "acef"]
    assert expand_braces("{x}{a,b}") == ["{x}a", "{x}b"]
    assert expand_word("r/none_*.json", tmp_path) == ["r/none_*.json"]  # no match: the word as it is
    assert with_output(["compare", "a.json", "b.json", "--plot", "docs/img/c"], tmp_path / "t") == [
        "compare", "a.json", "b.json", "--plot", str(tmp_path / "t")]
    assert uncommitted_inputs(["plot", "episode", "runs/x.json", "--out", "runs/y"]) == ["runs/x.json"]
