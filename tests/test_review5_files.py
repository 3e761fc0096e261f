"""Fifth review, input files: device files with unknown tables or keys or a noise scale outside the prior's box,
TOML files with a UTF-8 byte-order mark, object files in the wrong units (wavelength, degrees), and recordings whose
taxel layout, pressing depths, times or dimension order are not what the fit assumes."""

from __future__ import annotations

import re

import numpy as np
import pytest
import xarray as xr

from bayestouch.errors import BadInput
from bayestouch.inference.raw.data import load_raw_data
from bayestouch.io.device_file import DeviceCalibration, read_device_file, write_device_file
from bayestouch.params import MODELS
from bayestouch.scene.objects import load_object

SPHERE_REC = MODELS.parent / "data" / "recordings" / "sphere.nc"
SHAPE = "[shape]\ncentre_m = [0, 0, 0]\naxes_m = [0.03, 0.02, 0.02]\nn = 2\n"


@pytest.fixture
def device_text(tmp_path):
    cal = DeviceCalibration(np.zeros(256), np.full(256, 1e-3), 1.0, "physics", {"object": "sphere"}, 1.1, 1e-3)
    return write_device_file(tmp_path / "good.toml", cal).read_text()


# ------------------------------------------------------------------------------------------------- device files


def test_device_file_refuses_a_misspelt_table(tmp_path, device_text):
    """``[responce]`` (a typo) loaded with the response scale left at 1."""
    p = tmp_path / "typo.toml"
    p.write_text(device_text.replace("[response]", "[responce]"))
    with pytest.raises(BadInput, match=r"unknown table\(s\) \[responce\].*\[device\], \[gains\], \[response\]"):
        read_device_file(p)


def test_device_file_refuses_an_unknown_key(tmp_path, device_text):
    """An extra ``log_gains_sd`` in [gains] (or a key in [device] or [response]) was ignored."""
    for table, line in (
        ("[gains]", "log_gains_sd = [1.0]"),
        ("[device]", "noise_scal = 2.0"),
        ("[response]", "sd = 1"),
    ):
        p = tmp_path / "extra.toml"
        p.write_text(device_text.replace(table + "\n", f"{table}\n{line}\n"))
        key, name = line.split(" ")[0], re.escape(table)
        with pytest.raises(BadInput, match=rf"{name} unknown key\(s\) {key};"):
            read_device_file(p)
    assert read_device_file(tmp_path / "good.toml").response_scale == 1.1  # the untouched file still loads


@pytest.mark.parametrize("value", ["1e12", "1e-9", "0.05", "2e4"])
def test_device_file_refuses_a_noise_scale_outside_the_prior_box(tmp_path, device_text, value):
    """The fit's noise multiplier lives in [noise_scale_min, noise_scale_max] of models/priors.toml (0.1 to 1e4)."""
    p = tmp_path / "noise.toml"
    p.write_text(device_text.replace("noise_scale = 1.0", f"noise_scale = {value}"))
    with pytest.raises(BadInput, match=r"\[device\] noise_scale must be in \[0\.1, 10000\]"):
        read_device_file(p)
    for edge in ("0.1", "1e4"):
        p.write_text(device_text.replace("noise_scale = 1.0", f"noise_scale = {edge}"))
        assert read_device_file(p).noise_scale == float(edge)


# ------------------------------------------------------------------------------------------------- BOM


def test_a_byte_order_mark_is_accepted_in_object_and_device_files(tmp_path, device_text):
    """CSV and JSON inputs accept a UTF-8 BOM; TOML said 'Invalid statement (at line 1, column 1)'."""
    obj = tmp_path / "bom.toml"
    obj.write_bytes(b"\xef\xbb\xbf" + SHAPE.encode())
    assert np.allclose(np.asarray(load_object(obj).shape.axes), [0.03, 0.02, 0.02])
    dev = tmp_path / "bom_device.toml"
    dev.write_bytes(b"\xef\xbb\xbf" + device_text.encode())
    assert read_device_file(dev).response_scale == 1.1


# ------------------------------------------------------------------------------------------------- object files


@pytest.mark.parametrize("wavelength", ["1e-9", "2", "0.06", "9e-6"])
def test_object_texture_wavelength_outside_the_library_bounds_is_refused(tmp_path, wavelength):
    p = tmp_path / "tex.toml"
    p.write_text(SHAPE + f"[texture]\nwavelength_m = {wavelength}\namplitude_m = 5e-5\n")
    with pytest.raises(BadInput, match=r"'wavelength_m' must be in \[1e-05, 0\.05\] metres"):
        load_object(p)
    p.write_text(SHAPE + "[texture]\nwavelength_m = 0.05\namplitude_m = 5e-5\n")
    assert load_object(p).texture.wavelength == 0.05


def test_object_angles_in_degrees_are_refused(tmp_path):
    p = tmp_path / "deg.toml"
    p.write_text(SHAPE + "angles_rad = [0, 90, 45]\n")
    with pytest.raises(BadInput, match=r"'angles_rad'.*radians expected; 90 looks like degrees"):
        load_object(p)
    p.write_text(SHAPE + "angles_rad = [0, 6.2, -6.2]\n")
    assert np.allclose(np.asarray(load_object(p).shape.angles), [0, 6.2, -6.2])


# ------------------------------------------------------------------------------------------------- recordings


@pytest.fixture(scope="module")
def rec():
    with xr.open_dataset(SPHERE_REC, engine="h5netcdf") as ds:
        return ds.load()


def test_a_recording_with_another_taxel_layout_is_refused(rec):
    """``taxel_u`` × 1000 fitted exactly like the unedited file; the fit uses the finger model's grid."""
    with pytest.raises(BadInput, match=r"'taxel_u' differs from the finger's taxel layout"):
        load_raw_data(rec.assign_coords(taxel_u=rec.taxel_u * 1000))
    with pytest.raises(BadInput, match=r"'taxel_v' differs from the finger's taxel layout"):
        load_raw_data(rec.assign_coords(taxel_v=rec.taxel_v + 1e-5))
    # the taxels reordered together with their layout: each column's reading still sits at its own taxel_u
    order = np.random.default_rng(0).permutation(rec.sizes["taxel"])
    with pytest.raises(BadInput, match=r"'taxel_u' differs from the finger's taxel layout"):
        load_raw_data(rec.isel(taxel=order))
    load_raw_data(rec.assign_coords(taxel_u=rec.taxel_u + 1e-8))  # within the tolerance


def test_a_fit_refused_for_its_layout_leaves_no_run_folder(rec, tmp_path):
    """The layout is checked before the run folder is made: a refused fit leaves nothing behind (it left a folder
    with run.json)."""
    from bayestouch.inference.raw import run_raw_fit
    from bayestouch.io.recording import write_recording

    bad = write_recording(rec.assign_coords(taxel_u=rec.taxel_u * 1000), tmp_path / "uv_mm.nc")
    out = tmp_path / "run"
    with pytest.raises(BadInput, match=r"'taxel_u' differs from the finger's taxel layout"):
        run_raw_fit(bad, out, progress=False)
    assert not out.exists()


def test_a_pressing_depth_beyond_the_simulators_limit_is_refused(rec):
    """Depths × 100 (30 mm) fitted without a word; simulate and device run stop at MAX_DEPTH_M."""
    from bayestouch.physics.virtual import MAX_DEPTH_M

    with pytest.raises(BadInput, match=r"'pressing_depth' .* deeper than 0\.002 m"):
        load_raw_data(rec.assign(pressing_depth=rec.pressing_depth * 100))
    ok = rec.assign(pressing_depth=rec.pressing_depth * 0 + MAX_DEPTH_M)
    assert load_raw_data(ok)[0].frames.size > 0


def test_times_in_the_wrong_unit_are_refused(rec):
    """Times in ms with units s (frames 40 s apart), or in µs-as-ms (a pad sliding at 10 m/s)."""
    with pytest.raises(BadInput, match=r"'time' puts the frames 40 s apart .* frame rate"):
        load_raw_data(rec.assign_coords(time=rec.time * 1000))
    with pytest.raises(BadInput, match=r"'time' moves the pad at 10 m/s"):
        load_raw_data(rec.assign_coords(time=rec.time / 1000))
    with pytest.raises(BadInput, match=r"'time' puts the frames 4e-06 s apart"):
        load_raw_data(rec.assign_coords(time=rec.time / 10000, contact_point=rec.contact_point / 100))


def test_a_transposed_variable_is_named(rec, tmp_path):
    """A file with taxel_current stored (taxel, frame) blamed 'contact_point' for its shape."""
    bad = rec.assign(taxel_current=rec.taxel_current.transpose("taxel", "frame"))
    with pytest.raises(
        BadInput,
        match=r"'taxel_current' has dimensions \('taxel', 'frame'\); expected \('frame', 'taxel'\) \(transposed\?\)",
    ):
        load_raw_data(bad)
    p = tmp_path / "transposed.nc"
    bad.to_netcdf(p, engine="h5netcdf")
    with pytest.raises(BadInput, match=r"'taxel_current' has dimensions \('taxel', 'frame'\)"):
        load_raw_data(p)


def test_the_shipped_recordings_and_a_simulated_one_still_load(tmp_path):
    from bayestouch.api import simulate

    for p in sorted((MODELS.parent / "data" / "recordings").glob("*.nc")):
        assert load_raw_data(p)[0].frames.size >= 5
    ds = simulate("sphere", strokes=1, seed=3, duration=0.5, rate=100.0, depth=[2e-3])
    assert load_raw_data(ds, stride=1)[0].frames.size >= 5
