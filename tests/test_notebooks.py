"""The notebooks in notebooks/ (run by nbmake in `make test`): the six numbered ones exist, are stored without
outputs, read their sizes from BAYESTOUCH_NB_SMALL and write only into a temporary folder."""

import json
from pathlib import Path

import pytest

NOTEBOOKS = Path(__file__).parent.parent / "notebooks"
EXPECTED = (
    "01_forward_model_tour.ipynb",
    "02_shape_posterior_from_contacts.ipynb",
    "03_texture_and_contact_patch_posteriors.ipynb",
    "04_active_exploration.ipynb",
    "05_paper_reproduction.ipynb",
    "06_virtual_finger_serial_session.ipynb",
)


def unstripped(nb: dict) -> list[str]:
    """What keeps a notebook from being stripped: cell outputs, execution counts, widget state."""
    problems = []
    for i, cell in enumerate(nb["cells"]):
        if cell["cell_type"] != "code":
            continue
        if cell.get("outputs"):
            problems.append(f"cell {i}: outputs")
        if cell.get("execution_count") is not None:
            problems.append(f"cell {i}: execution_count {cell['execution_count']}")
    if "widgets" in nb.get("metadata", {}):
        problems.append("metadata: widget state")
    return problems


def _load(name):
    return json.loads((NOTEBOOKS / name).read_text(encoding="utf-8"))


def test_the_six_numbered_notebooks_exist():
    assert tuple(sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))) == EXPECTED


@pytest.mark.parametrize("name", EXPECTED)
def test_notebook_is_stripped_and_sized_by_the_environment(name):
    nb = _load(name)
    assert unstripped(nb) == []
    assert nb["metadata"]["kernelspec"]["name"] == "python3"  # the kernel of the interpreter running pytest
    code = ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    # the first code cell sets the sizes from the environment and the output folder in a temporary directory
    assert 'os.environ.get("BAYESTOUCH_NB_SMALL"' in code[0] and "SMALL" in code[0]
    assert "OUT = Path(tempfile.mkdtemp(" in code[0]
    assert nb["cells"][0]["cell_type"] == "markdown" and "".join(nb["cells"][0]["source"]).startswith("# 0")
    assert sum("assert " in c for c in code) >= 1  # each checks a fact
    assert not any(".to_csv(ROOT" in c or "write_recording(ds, ROOT" in c for c in code)


def test_unstripped_notebook_is_detected():
    """Negative control for the check above: an executed cell is reported."""
    nb = _load(EXPECTED[0])
    cell = next(c for c in nb["cells"] if c["cell_type"] == "code")
    cell["execution_count"] = 1
    cell["outputs"] = [{"output_type": "stream", "name": "stdout", "text": "hello"}]
    assert unstripped(nb) == ["cell 1: outputs", "cell 1: execution_count 1"]
