"""Parameter files: unit, range and source checks with one-line errors."""

import pytest

from bayestouch.errors import BadInput
from bayestouch.params import Spec, read_section, read_toml

SPECS = {"diameter": Spec("m", 0.0, 1e-3), "current": Spec("A", 0.0, 2.0)}


def _doc(**over):
    tab = {
        "diameter": {"value": 1e-4, "unit": "m", "source": "Dynalloy"},
        "current": {"value": 0.15, "unit": "A", "source": "physics.md §1"},
    }
    tab.update(over)
    return {"wire": tab}


def test_good_section():
    assert read_section(_doc(), "wire", SPECS, "f.toml") == {"diameter": 1e-4, "current": 0.15}


@pytest.mark.parametrize(
    "over,needle",
    [
        ({"diameter": {"value": 100, "unit": "um", "source": "x"}}, 'unit must be "m"'),
        ({"diameter": {"value": float("nan"), "unit": "m", "source": "x"}}, "finite"),
        ({"diameter": {"value": 1e-4, "unit": "m"}}, "source"),
        ({"diameter": 1e-4}, "inline table"),
        ({"current": {"value": 5.0, "unit": "A", "source": "x"}}, "outside the allowed range"),
        ({"colour": {"value": 1.0, "unit": "", "source": "x"}}, "unknown constant(s) colour"),
    ],
)
def test_bad_sections(over, needle):
    with pytest.raises(BadInput) as e:
        read_section(_doc(**over), "wire", SPECS, "f.toml")
    assert needle in str(e.value) and str(e.value).startswith("f.toml [wire]") and "\n" not in str(e.value)


def test_missing_entries_and_files(tmp_path):
    doc = _doc()
    del doc["wire"]["current"]
    with pytest.raises(BadInput, match="current: missing"):
        read_section(doc, "wire", SPECS, "f.toml")
    with pytest.raises(BadInput, match=r"missing table \[rod\]"):
        read_section(doc, "rod", SPECS, "f.toml")
    with pytest.raises(BadInput, match="no such file"):
        read_toml(tmp_path / "none.toml")
    with pytest.raises(BadInput, match=r"is a folder, not a file \(expected a TOML file"):
        read_toml(tmp_path)
    (tmp_path / "bad.toml").write_text("x = {")
    with pytest.raises(BadInput, match="not valid TOML"):
        read_toml(tmp_path / "bad.toml")
