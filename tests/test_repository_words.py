"""
The repository speaks of the project only: no numbered work periods, tracker numbers, files that are not in the
repository, or recipes named by letter instead of by what they are.

Every tracked text file is read (``git ls-files``); binary files are skipped. Each pattern is precise enough to leave
legitimate words alone (``start_new_session=True``, an HTTP or TensorBoard session, "a recipe a user writes").
"""

import pathlib
import re
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
THIS_FILE = pathlib.Path(__file__).resolve()

# (what is wrong, pattern). Whitespace in the patterns is ``\s+`` so that a phrase broken over two lines is found too.
FORBIDDEN = [
    ("a numbered work period", re.compile(r"\bsessions?[ -]?\d+", re.IGNORECASE)),
    (
        "a work period named relative to another",
        re.compile(
            r"\b(?:this|that|previous|next|last|earlier|later|current|same|each|every|one|another|new)\s+sessions?\b",
            re.IGNORECASE,
        ),
    ),
    ("a work period's time or end", re.compile(r"\bthe\s+session(?:'s|\s+ended|\s+ends|\s+ran\s+out)", re.IGNORECASE)),
    ("a tracker number", re.compile(r"\bissues?\s+#?\d+", re.IGNORECASE)),
    ("a file outside the repository", re.compile(r"\bMISSION\.md\b", re.IGNORECASE)),
    ("a path outside the repository", re.compile(r"\bshared/seed", re.IGNORECASE)),
    # Case-sensitive letters: "recipe A" is a letter name, "a recipe a user writes" is English.
    ("a recipe named by letter", re.compile(r"\b[Rr]ecipes?\s+[A-F]'?(?![\w'])")),
    ("a recipe named by letter", re.compile(r"\b(?:GACL|BC2L|MECL|VICRL)\s+\(?[A-F]'?\)?(?=[\s,.;:)]|$)")),
]


def tracked_text_files() -> list[pathlib.Path]:
    """The tracked files that decode as UTF-8 text, this test excluded."""
    try:
        listing = subprocess.run(
            ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, timeout=60
        ).stdout.decode()
    except (OSError, subprocess.CalledProcessError) as error:
        pytest.skip(f"not a git checkout ({error}); the tracked files cannot be listed")
    files = []
    for name in filter(None, listing.split("\0")):
        path = ROOT / name
        if path.resolve() == THIS_FILE or not path.is_file():
            continue
        with path.open("rb") as file:
            if b"\0" in file.read(8192):
                continue
        try:
            path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        files.append(path)
    return files


def find_process_words(text: str) -> list[tuple[int, str, str]]:
    """
    Every forbidden phrase in ``text``.

    :param text: The contents of one file
    :return: (line number, what is wrong, the phrase) for each hit, in order of position
    """
    hits = []
    for reason, pattern in FORBIDDEN:
        for match in pattern.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            hits.append((match.start(), line, reason, " ".join(match.group().split())))
    return [(line, reason, phrase) for _, line, reason, phrase in sorted(hits)]


@pytest.mark.parametrize(
    "text",
    [
        "results of session 3",
        "the session-2 expert",
        "Sessions 6 and 7",
        "new this session;",
        "left for the next\nsession",
        "when the session's time ran out",
        "until the session\nended",
        "see issue 7",
        "issue #12",
        "MISSION.md's table",
        "under /tmp/shared/seed_0",
        "Recipe E, now the entry",
        "recipe E' (below)",
        "MECL (D) at 1.7M",
        "VICRL E' + match",
        "| MECL E | 123 |",
    ],
)
def test_process_words_are_found(text):
    assert find_process_words(text), text


@pytest.mark.parametrize(
    "text",
    [
        "subprocess.Popen(command, start_new_session=True)",
        "with tf.Session() as session:",
        "an HTTP session keeps cookies",
        "a recipe a user writes",
        "the recipe: four envs x 128 steps",
        "MECL and VICRL recipes",
        "the issue tracker",
        "VICRL E[x] of the Beta",
        "MECL Ant-v5",
        "beta(A, B)",
    ],
)
def test_legitimate_words_are_left_alone(text):
    assert find_process_words(text) == []


def test_tracked_files_speak_of_the_project_only():
    files = tracked_text_files()
    assert any(path.name == "README.md" for path in files), "README.md should be among the tracked text files"
    problems = [
        f"{path.relative_to(ROOT)}:{line}: {reason}: {phrase!r}"
        for path in files
        for line, reason, phrase in find_process_words(path.read_text(encoding="utf-8"))
    ]
    assert not problems, "Reword these in the project's own terms (what was measured, when, with which settings):\n" + (
        "\n".join(problems)
    )
