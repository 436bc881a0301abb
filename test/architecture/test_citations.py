"""Every citation names the paper, never a file or an issue.

Code, docs and data files of the repository must not give a working document, a seed file
or an issue tracker entry as the source of a fact: those are not part of the repository,
so a reader cannot follow them. A fact is cited by the paper (authors, title, equation,
table or section) or stated in words. Links between the repository's own documents (the
README to ``docs/*.md``, ``CHANGELOG.rst``, ``LICENSE``) and cross-references to the
project's modules are not citations and pass.

The scan covers every file git tracks or would track (untracked but not ignored), with the
text suffixes below; virtual environments, build trees, run outputs and the recorded bags
are skipped, and so is this file (its patterns and samples are citations on purpose). A
failure lists ``file:line: rule: text`` for each hit.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

SELF = Path(__file__).resolve()
REPO = SELF.parents[2]
SUFFIXES = {".py", ".md", ".rst", ".yaml", ".yml", ".toml", ".msg", ".xml", ".txt", ".sh"}
SKIP_DIRS = {".venv", "venv", "build", "install", "log", "runs", "bags", ".git", "__pycache__"}
MAX_BYTES = 2_000_000

#: Documents of the project's brief and the seed literature's file layout: never in the
#: repository, so never a source.
_BRIEF_DOCS = r"(?:design|layout|ros-conventions|ros2-on-pypi|seeds-digest)"
#: (name, pattern) of a citation of a file or an issue. Case-insensitive.
PATTERNS: tuple[tuple[str, re.Pattern], ...] = tuple(
    (name, re.compile(rx, re.IGNORECASE))
    for name, rx in (
        ("brief document", _BRIEF_DOCS + r"\.md\b"),
        ("brief document", r"\bseeds-digest\b|\bshared/docs\b|(?<![\w.-])seeds/"),
        ("design principle by number", r"\bprinciples?\s+\d+\b|\bdesign\s+principle\b"),
        ("issue by number", r"\bissues?\s*#?\s*\d+\b"),
        ("issue as a source", r"\(\s*issues?\b"),
        ("issue as a source", r"\bthe\s+issue'?s\b|\bissues'"),
        ("issue as a source", r"\bissues?\b[^.\n]{0,25}\b(?:acceptance|asks|asked)\b"),
        ("issue as a table column", r"[\"']issues?[\"']"),
        ("seed file", r"\b(?:chen2018|zhang2010)_\w+|\bpetkov_stochastic\w*|\bcolinet_pulse\w*"),
        (
            "file as a source",
            r"\b(?:see|cf\.?|documented\s+in|described\s+in|explained\s+in|details\s+in"
            r"|(?:the\s+)?notes\s+in)\s+(?:the\s+)?[`'\"]*[\w./-]+\.(?:py|md)\b",
        ),
        ("file as a source", r"\b(?:see|cf\.?)\s+[`'\"]*(?:test|bench)/"),
        ("file as a source", r"[(,;]\s*`*[\w./-]+\.py`*\s*\)"),
    )
)
#: Any mention of a Markdown file: passes only if it names a file of this repository.
MD_MENTION = re.compile(r"[\w./-]*\w\.md\b")
BRIEF_NAME = re.compile(r"^" + _BRIEF_DOCS + r"\.md$", re.IGNORECASE)


def markdown_target_exists(mention: str, source: Path, root: Path = REPO) -> bool:
    """True if ``mention`` (a ``.md`` path as written in ``source``) is a file of the
    repository, relative to the citing file's folder or to the repository root, and not a
    document of the brief."""
    if BRIEF_NAME.match(Path(mention).name):
        return False
    for base in (source.parent, root):
        target = (base / mention).resolve()
        if target.is_file() and root in target.parents:
            return True
    return False


def line_hits(line: str, source: Path, root: Path = REPO) -> list[str]:
    """Names of the citation rules one line of ``source`` breaks (empty if clean)."""
    hits = [name for name, rx in PATTERNS if rx.search(line)]
    for m in MD_MENTION.finditer(line):
        if not markdown_target_exists(m.group(0), source, root):
            hits.append(f"Markdown file not in the repository ({m.group(0)})")
    return hits


def scanned_files(root: Path = REPO) -> list[Path]:
    """Text files of the repository: tracked or trackable (git), else a directory walk;
    this file excluded."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
            cwd=root,
            capture_output=True,
            check=True,
        ).stdout.decode()
        paths = [root / p for p in out.split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        paths = [p for p in root.rglob("*") if p.is_file()]
    files = []
    for p in sorted(set(paths)):
        rel = p.relative_to(root)
        if SKIP_DIRS & set(rel.parts[:-1]) or p.suffix not in SUFFIXES or not p.is_file():
            continue
        if p.resolve() == SELF:
            continue
        if p.stat().st_size <= MAX_BYTES:
            files.append(p)
    return files


def citation_hits(root: Path = REPO) -> list[str]:
    """``file:line: rule: text`` for every citation of a file or an issue."""
    found = []
    for path in scanned_files(root):
        text = path.read_text(encoding="utf-8", errors="replace")
        for no, line in enumerate(text.splitlines(), 1):
            rules = line_hits(line, path, root)
            if rules:
                rule = "; ".join(dict.fromkeys(rules))
                found.append(f"{path.relative_to(root)}:{no}: {rule}: {line.strip()[:120]}")
    return found


def test_no_citation_of_a_file_or_an_issue():
    hits = citation_hits()
    assert not hits, (
        "cite the paper (authors, title, equation/table/section) or state the fact in words:\n"
        + "\n".join(hits)
    )


_MD = ".md"
#: Lines that cite a file or an issue (each must be flagged).
BAD_LINES = (
    "Deterministic (design.md principle 4).",
    "seed ``chen2018_capacitive_motion_estimation_gyro_calibration_microscanner.md``",
    "Source: Petkov (seed ``petkov_stochastic_models_mems_inertial_sensors.md``)",
    "Source: Chen 2018 (seed ``chen2018_...microscanner.md``)",
    "see the seeds-digest, section 7",
    "the graph stays local (Principle 7 of the design)",
    "# issue 3: <= 100 ppm RMS over the two temperatures",
    "scale-factor calibration (Chen 2018, chapter 3; issue 3).",
    "End-to-end through the node graph (issue 6).",
    "tracked as issue #12",
    "The scenario's results next to the paper's and the issue's figures.",
    "Issue 4 acceptance:",
    "the issue asks the UKF to beat the EKF",
    'format_table(["figure", "paper", "issue", "measured"], rows)',
    "second-order leakage (see test/mems_sim/devices/test_stage.py)",
    "the table lives in one place (see mems_sim/params.py)",
    "they are too narrow (see the notes in mems_estimation/noise_id.py)",
    "documented in `mems_sim/micro_stage.py`",
    "keeps up only with frames of 10^4 samples, bench_scanner.py).",
    "see test_fr_accelerometer.py",
    "see ../seeds/colinet.md",
    "installs ROS 2 from PyPI wheels (see ros2-on-pypi.md)",
)
#: Ordinary prose, code and links inside the repository (none may be flagged).
GOOD_LINES = (
    "the causal detector issues the detection of sample c at sample k",
    "detections issued during the frame; it issues a warning when the SNR is low",
    "- [IMU](docs/imu.md), [stage](docs/stage.md)",
    "- [CHANGELOG.rst](CHANGELOG.rst), [LICENSE](LICENSE) (Apache-2.0).",
    'Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using '
    'digital Kalman observer", Sec. 2, eqs. (2)-(6).',
    "Petkov & Slavov, Stochastic Modeling of MEMS Inertial Sensors, eq. (6) is misprinted.",
    "deterministic: every random source is seeded from the run seed",
    "Run:  .venv/bin/python bench/bench_allan.py [n_samples]",
    "Device models: :mod:`mems_sim.devices.imu` (see :func:`discrete_gm_coefficients`).",
    "the same seed as the exact case; the run seed and the device seed",
    "model, _ = identify_stage(seed=6, plan=Plan.short())",
    "The architecture test `test/architecture/test_import_rule.py` enforces it.",
    "Real-time behaviour is in [testing.md](testing.md#the-stage-graph).",
)


def test_patterns_catch_bad_lines_and_pass_good_ones():
    readme = REPO / "README.md"
    for line in BAD_LINES:
        assert line_hits(line, readme), f"not flagged: {line!r}"
    for line in GOOD_LINES:
        source = REPO / "docs" / "stage.md" if "testing" in line else readme
        assert not line_hits(line, source), f"flagged: {line!r}: {line_hits(line, source)}"


def test_markdown_links_resolve_relative_to_the_citing_file(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("x")
    (tmp_path / ("design" + _MD)).write_text("x")
    src = tmp_path / "docs" / "b.md"
    assert markdown_target_exists("a.md", src, tmp_path)
    assert markdown_target_exists("docs/a.md", tmp_path / "README.md", tmp_path)
    assert not markdown_target_exists("missing.md", src, tmp_path)
    # a brief document is never a source, even if a copy sits in the tree
    assert not markdown_target_exists("design" + _MD, tmp_path / "README.md", tmp_path)
