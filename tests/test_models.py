"""Every parameter set in models/ loads, and a broken copy of each is refused on load with one line naming the file
and the entry (issue 7: "every TOML parameter set validated on load with clear errors")."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.params import MODELS


def _loaders():
    from bayestouch.inference.contact import load_priors
    from bayestouch.inference.ffd_marginal import load_ffd_priors
    from bayestouch.inference.patch import load_patch_priors
    from bayestouch.inference.raw import load_raw_priors
    from bayestouch.physics.bending import load_rod
    from bayestouch.physics.noise import load_noise
    from bayestouch.physics.skin import load_skin
    from bayestouch.physics.sma import load_wire
    from bayestouch.physics.taxel import load_taxels

    return {
        "finger.toml/wire": ("finger.toml", load_wire),
        "finger.toml/rod": ("finger.toml", load_rod),
        "noise.toml": ("noise.toml", load_noise),
        "priors.toml": ("priors.toml", load_priors),
        "priors.toml/raw": ("priors.toml", load_raw_priors),
        "priors.toml/patch": ("priors.toml", load_patch_priors),
        "priors.toml/ffd": ("priors.toml", load_ffd_priors),
        "skin.toml": ("skin.toml", load_skin),
        "taxels.toml": ("taxels.toml", load_taxels),
    }


CASES = [
    "finger.toml/wire",
    "finger.toml/rod",
    "noise.toml",
    "priors.toml",
    "priors.toml/raw",
    "priors.toml/patch",
    "priors.toml/ffd",
    "skin.toml",
    "taxels.toml",
]


@pytest.mark.parametrize("case", CASES)
def test_shipped_parameter_sets_load(case):
    name, load = _loaders()[case]
    assert load(MODELS / name) is not None


def _broken(tmp_path, name: str, how: str):
    """A copy of models/<name> broken in one way: a unit changed, a value made non-finite, or an entry removed."""
    text = (MODELS / name).read_text()
    if how == "unit":
        new = re.sub(r'unit = "[^"]*"', 'unit = "furlong"', text, count=1)
    elif how == "value":
        new = re.sub(r"value = [^,}]+", "value = nan", text, count=1)
    else:  # drop the first entry that has a unit
        lines = text.splitlines(keepends=True)
        k = next(i for i, line in enumerate(lines) if "unit = " in line and not line.lstrip().startswith("#"))
        new = "".join(lines[:k] + lines[k + 1 :])
    assert new != text
    path = tmp_path / name
    path.write_text(new)
    return path


@pytest.mark.parametrize("how", ["unit", "value", "missing"])
@pytest.mark.parametrize("case", CASES)
def test_a_broken_parameter_set_is_refused_with_one_line(case, how, tmp_path):
    name, load = _loaders()[case]
    path = _broken(tmp_path, name, how)
    try:
        load(path)
    except BadInput as e:
        msg = str(e)
        assert "\n" not in msg and name in msg, msg
        return
    # the broken entry may belong to another table of the same file (finger.toml holds wire and rod): then the
    # loader of that table must refuse it
    others = [c for c in CASES if c != case and _loaders()[c][0] == name]
    assert others, f"{case}: a {how} fault was accepted"
    with pytest.raises(BadInput, match=re.escape(name)):
        _loaders()[others[0]][1](path)


def test_objects_load_and_a_missing_one_is_named(tmp_path):
    from bayestouch.scene.objects import load_object

    for path in sorted((MODELS / "objects").glob("*.toml")):
        assert load_object(path).name
    with pytest.raises(BadInput, match="nothing.toml"):
        load_object(tmp_path / "nothing.toml")
    shutil.copy(MODELS / "objects" / "egg.toml", tmp_path / "egg.toml")
    text = (tmp_path / "egg.toml").read_text().replace("n = 2.2", "n = -1")
    (tmp_path / "egg.toml").write_text(text)
    with pytest.raises(BadInput) as e:
        load_object(tmp_path / "egg.toml")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "case,entry",
    [("priors.toml/raw", "log_noise_scale_sd"), ("priors.toml/patch", "n_max"), ("priors.toml/ffd", "tau")],
)
def test_each_prior_table_refuses_its_own_broken_entry(case, entry, tmp_path):
    """The raw, patch and FFD prior tables are validated on their own: an entry of theirs removed or non-finite is
    refused with one line naming the file and the entry."""
    name, load = _loaders()[case]
    text = (MODELS / name).read_text()
    assert load(MODELS / name)[entry] > 0
    dropped = re.sub(rf"(?m)^{entry} = .*\n", "", text)
    for new in (dropped, re.sub(rf"(?m)^({entry} = {{ value = )[^,]+", r"\1nan", text)):
        assert new != text
        (tmp_path / name).write_text(new)
        with pytest.raises(BadInput, match=re.escape(name)) as e:
            load(tmp_path / name)
        assert entry in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_shipped_objects_load_by_name_from_any_folder(tmp_path, monkeypatch):
    """``load_object("egg")`` reads the shipped egg wherever the caller stands; an unknown name names the known
    ones."""
    from bayestouch.scene.objects import OBJECTS_DIR, load_object

    monkeypatch.chdir(tmp_path)
    by_name, by_path = load_object("egg"), load_object(OBJECTS_DIR / "egg.toml")
    assert by_name.name == by_path.name == "egg"
    assert by_name.source.resolve() == by_path.source.resolve()
    for a, b in zip(by_name.shape, by_path.shape, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(BadInput, match="unknown object 'eggo'.*sphere"):
        load_object("eggo")
