"""The README quotes only committed results: its measured table is exactly what benchmarks/readme.py renders from
benchmarks/results/, and every result file a row names exists."""

import re
from pathlib import Path

import pytest

from benchmarks import readme as rd

ROOT = Path(__file__).resolve().parent.parent


def test_readme_table_is_rendered_from_the_committed_results():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert text.count(rd.BEGIN) == 1 and text.count(rd.END) == 1
    block = text[text.index(rd.BEGIN) : text.index(rd.END) + len(rd.END)]
    assert block == rd.render(rd.RESULTS), (
        "README's measured table differs from the results: python -m benchmarks.readme"
    )
    rows = [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| What")]
    assert len(rows) >= 3  # the raw, mismatch and users'-sets rows at least
    for name in re.findall(r"benchmarks/results/([\w.]+\.json)", block):
        assert (rd.RESULTS / name).is_file(), name


def test_a_changed_result_changes_the_table(tmp_path):
    """Negative control: the rendering reads the numbers (a result edited by hand no longer agrees)."""
    import json
    import shutil

    for p in rd.RESULTS.glob("*.json"):
        shutil.copy(p, tmp_path / p.name)
    doc = json.loads((tmp_path / "mismatch.json").read_text())
    doc["volume"]["covered"] += 1
    (tmp_path / "mismatch.json").write_text(json.dumps(doc))
    assert rd.render(tmp_path) != rd.render(rd.RESULTS)
    (tmp_path / "mismatch.json").unlink()
    # the row's source named exactly (texture_mismatch.json's row names its own file)
    assert "mismatch.json" in rd.missing(tmp_path) and "(`benchmarks/results/mismatch.json`)" not in rd.render(tmp_path)


def test_update_rewrites_only_the_block(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n\n{rd.BEGIN}\nstale\n{rd.END}\n\noutro\n", encoding="utf-8")
    assert rd.update_readme(readme, rd.RESULTS)
    text = readme.read_text(encoding="utf-8")
    assert text.startswith("intro\n\n") and text.endswith("\n\noutro\n") and "stale" not in text
    assert not rd.update_readme(readme, rd.RESULTS)
    readme.write_text("no block", encoding="utf-8")
    with pytest.raises(SystemExit, match="no measured block"):
        rd.update_readme(readme, rd.RESULTS)


def test_readme_pictures_and_links_exist():
    """Every picture and every repository path the README links to is in the repository."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)#\s]+)\)", text)
    assert any(t.endswith(".png") for t in targets)
    for t in targets:
        if "://" not in t:
            assert (ROOT / t).exists(), t


def _cells(line: str) -> int:
    """Columns of a Markdown table row: its pipes less the escaped ones, less one."""
    return len(re.findall(r"(?<!\\)\|", line)) - 1


@pytest.mark.parametrize("path", ["README.md", "benchmarks/results/README.md"])
def test_every_table_row_has_its_header_s_columns(path):
    """A metric such as "median |z|" written unescaped splits its row into more columns than the header has, and
    the renderer shifts every cell after it; each table's rows have as many columns as its header."""
    lines = (ROOT / path).read_text(encoding="utf-8").splitlines()
    header = None
    for line in lines:
        if not line.startswith("|"):
            header = None
        elif header is None:
            header = _cells(line)
        else:
            assert _cells(line) == header, line[:120]
