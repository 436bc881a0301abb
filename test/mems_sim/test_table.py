"""Summary tables and lines fit a 120-column terminal, every word kept."""

from __future__ import annotations

from mems_sim.table import MAX_WIDTH, fit_lines, format_table


def test_narrow_table_is_unchanged():
    text = format_table(["name", "value"], [["a", "1"], ["bb", "22"]])
    assert text.splitlines() == ["name  value", "----  -----", "   a      1", "  bb     22"]


def test_wide_table_wraps_its_widest_cells_within_120_columns():
    long = "EKF loop: x error mean / std vs predicted (zero mean, std within 20 % of the filter's)"
    header = ["figure", "target", "measured", "met"]
    rows = [[long, "|mean| <= 3 se, std within 20 %", long.upper(), "yes"], ["b", "-", "1", "NO"]]
    lines = format_table(header, rows).splitlines()
    assert len(lines) > 4 and max(map(len, lines)) <= MAX_WIDTH
    words = " ".join(" ".join(r) for r in [header] + rows).split()
    body = [line for line in lines if set(line) - {"-", " "}]  # without the rule
    assert len(body) == len(lines) - 1
    assert sorted(" ".join(body).split()) == sorted(words)
    assert lines[-1].split() == ["b", "-", "1", "NO"]  # a short row stays one line


def test_long_lines_wrap_at_spaces_and_keep_long_words():
    topics = ", ".join(f"/device_{k}/adc {k}" for k in range(40))
    line = f"recorded runs/x-1.mcap: {topics}"
    out = fit_lines("short\n" + line).splitlines()
    assert out[0] == "short" and max(map(len, out)) <= MAX_WIDTH
    assert " ".join(out[1:]).replace("   ", " ").split() == line.split()
    assert all(o.startswith("  ") for o in out[2:])
    word = "/tmp/" + "x" * 130
    assert fit_lines(word) == word  # a path is never broken
