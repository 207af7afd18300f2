"""benchmarks/common.write_results: a benchmark's table in its own marked section of RESULTS.md."""

import re
from pathlib import Path

import pytest

from benchmarks.common import results_section, write_results

HEAD = "# Benchmark results\n\n## Where things stand\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n"
WHEN = {"command": ".venv/bin/python benchmarks/x.py --fast", "machine": "x86_64, 2 CPU cores", "date": "2026-11-29"}


def section(name: str, number: str) -> str:
    return results_section(name, f"| n |\n|---|\n| {number} |", f"{number} (target < 5)", **WHEN)


def test_the_section_names_date_machine_command_table_and_where_it_stands():
    text = section("pattern", "3")
    assert text.splitlines() == [
        "<!-- bench:pattern -->", "- Date: 2026-11-29", "- Machine: x86_64, 2 CPU cores",
        "- Command: `.venv/bin/python benchmarks/x.py --fast`", "", "| n |", "|---|", "| 3 |", "",
        "Where it stands: 3 (target < 5)", "<!-- /bench:pattern -->"]


def test_replaces_only_its_own_section(tmp_path):
    path = tmp_path / "RESULTS.md"
    tail = "\nProse after the section, kept.\n"
    path.write_text(HEAD + "## Pattern\n\nWhat it measures.\n\n" + section("pattern", "3") + tail
                    + "\n## Body\n\n" + section("body", "7") + "\nLast line without a newline")
    before = path.read_text()
    write_results("pattern", "| n |\n|---|\n| 4 |", "4 (target < 5)", path=path, **WHEN)
    after = path.read_text()
    assert after == before.replace(section("pattern", "3"), section("pattern", "4"))
    assert section("body", "7") in after and after.endswith("Last line without a newline")
    assert not list(tmp_path.glob(".*part"))  # the atomic write leaves no temporary file


def test_inserts_a_missing_section_at_the_end(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text(HEAD + section("body", "7"))
    write_results("pattern", "| n |\n|---|\n| 3 |", "3 (target < 5)", path=path, **WHEN)
    assert path.read_text() == HEAD + section("body", "7") + "\n" + section("pattern", "3")
    write_results("pattern", "| n |\n|---|\n| 3 |", "3 (target < 5)", path=path, **WHEN)  # then replaces it
    assert path.read_text().count("<!-- bench:pattern -->") == 1


def test_a_missing_file_is_made(tmp_path):
    path = tmp_path / "RESULTS.md"
    write_results("body", "| n |\n|---|\n| 7 |", "7 (target < 5)", path=path, **WHEN)
    assert path.read_text() == section("body", "7")


@pytest.mark.parametrize("text, line, words", [
    (HEAD + "<!-- bench:pattern -->\n| 3 |\n", 9, "has no <!-- /bench:pattern -->"),
    (HEAD + "| 3 |\n<!-- /bench:pattern -->\n", 10, "closes a section that is not open"),
    (HEAD + "<!-- bench:pattern -->\n<!-- bench:body -->\n<!-- /bench:body -->\n", 10, "opens inside section 'pattern'"),
    (HEAD + "<!-- bench:body -->\n<!-- /bench:pattern -->\n", 10, "closes a section that is not open"),
    (HEAD + section("body", "1") + section("body", "2"), 20, "a second section 'body'"),
])
def test_refuses_malformed_markers_naming_the_line(tmp_path, text, line, words):
    path = tmp_path / "RESULTS.md"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"line {line}: .*{words}"):
        write_results("pattern", "| n |\n|---|\n| 3 |", "3", path=path, **WHEN)
    assert path.read_text() == text  # nothing written


def test_a_name_that_would_not_make_a_marker_is_refused(tmp_path):
    with pytest.raises(ValueError, match="benchmark name"):
        write_results("two words", "| n |", "-", path=tmp_path / "R.md", **WHEN)


def test_every_script_of_make_bench_writes_its_section_and_takes_no_results():
    root = Path(__file__).resolve().parents[1]
    makefile = (root / "Makefile").read_text()
    recipe = makefile[makefile.index("\nbench:"):].split("\n\n")[0]
    scripts = re.findall(r"benchmarks/(\w+)\.py", recipe)
    assert len(scripts) >= 7, recipe
    results = (root / "benchmarks" / "RESULTS.md").read_text()
    for name in scripts:
        source = (root / "benchmarks" / f"{name}.py").read_text()
        assert f'write_results("{name}"' in source and "add_results_flag(parser)" in source, name
        assert f"<!-- bench:{name} -->" in results, name  # its table is replaced, not appended
