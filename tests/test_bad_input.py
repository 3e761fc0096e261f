"""Bad input anywhere on the command line: one line on stderr naming the problem, exit code 2, no traceback, and
nothing already recorded is lost.

The table below is the record of the inputs tried (issue 7): each row is a command line (``{tmp}`` is a fresh folder
holding the fixture files written by :func:`_files`) and a piece of the message it must print.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import xarray as xr

from bayestouch.cli import main
from bayestouch.io.device_file import DeviceCalibration, write_device_file
from bayestouch.params import MODELS

#: command line, text the one-line message must contain
TABLE = [
    # missing files and folders
    ("fit {tmp}/missing.csv --out {tmp}/o", "missing.csv"),
    ("fit {tmp}/missing.nc --out {tmp}/o", "missing.nc"),
    ("simulate --object {tmp}/missing.toml --out {tmp}/r.nc", "missing.toml"),
    # issue 24, ninth review: an empty name was "unknown object '.'", a folder an unknown object
    ("simulate --object= --out {tmp}/r.nc", "object: got an empty name"),
    ("simulate --object {tmp} --out {tmp}/r.nc", "is a folder; expected an object name"),
    ("reproduce-paper --object {tmp}/missing.toml --out {tmp}/o", "missing.toml"),
    ("explore --object {tmp}/missing.toml --out {tmp}/o", "missing.toml"),
    ("device run --port {tmp}/no_such_port --strokes 1 --out {tmp}/r.nc", "no_such_port"),
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/missing.json --out {tmp}/r.nc", "missing.json"),
    # wrong schema
    ("fit {tmp}/no_header.csv --out {tmp}/o", "x,y,z"),
    ("fit {tmp}/wrong_columns.csv --out {tmp}/o", "x,y,z"),
    ("fit {tmp}/text_values.csv --out {tmp}/o", "text_values.csv"),
    ("fit {tmp}/nan_values.csv --out {tmp}/o", "nan_values.csv"),
    ("fit {tmp}/empty.csv --out {tmp}/o", "empty.csv"),
    ("fit {tmp}/not_a_recording.nc --out {tmp}/o", "not_a_recording.nc"),
    ("simulate --object {tmp}/no_shape.toml --out {tmp}/r.nc", "shape"),
    ("simulate --object {tmp}/broken.toml --out {tmp}/r.nc", "broken.toml"),
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/bad_strokes.json --out {tmp}/r.nc", "bad_strokes.json"),
    # wrong units
    ("fit {tmp}/millimetres.csv --out {tmp}/o", "metres"),
    ("simulate --object {tmp}/millimetres.toml --out {tmp}/r.nc", "millimetres"),
    ("simulate --object {egg} --out {tmp}/r.nc --depth 0.3", "depth"),
    ("simulate --object {egg} --out {tmp}/r.nc --currents 150,50,50", "current"),
    ("simulate --object {egg} --out {tmp}/r.nc --force 70", "--force"),
    # impossible parameters
    ("simulate --object {tmp}/negative_axes.toml --out {tmp}/r.nc", "axes"),
    ("fit {tmp}/huge.csv --out {tmp}/o", "--subsample"),
    ("fit {tmp}/micrometres.csv --out {tmp}/o", "span only"),
    ("fit {tmp}/good.csv --out {tmp}/o --subsample 10", "--subsample"),
    # the parts fit reads its contacts as the single fit does (--subsample was ignored there)
    ("fit {tmp}/good.csv --out {tmp}/o --parts 1 --subsample 10", "--subsample"),
    ("fit {tmp}/huge.csv --out {tmp}/o --parts 1", "--subsample"),
    ("simulate --object {tmp}/nan_axes.toml --out {tmp}/r.nc", "finite"),
    ("simulate --object {egg} --strokes 1000000000 --out {tmp}/r.nc", "split it"),
    ("simulate --object {tmp}/huge_n.toml --out {tmp}/r.nc", "'n' must be in"),
    ("simulate --object {tmp}/negative_modes.toml --out {tmp}/r.nc", "'modes'"),
    ("simulate --object {tmp}/negative_seed.toml --out {tmp}/r.nc", "'seed'"),
    ("simulate --object {egg} --out {tmp}/r.nc --duration -1", "--duration"),
    ("simulate --object {egg} --out {tmp}/r.nc --rate 0", "--rate"),
    ("simulate --object {egg} --out {tmp}/r.nc --currents 0.1,0.1", "three"),
    ("simulate --object {egg} --out {tmp}/r.txt", ".nc"),
    ("fit {tmp}/good.csv --out {tmp}/o --walkers 7", "--walkers"),
    ("fit {tmp}/good.csv --out {tmp}/o --budget -1", "--budget"),
    ("fit {tmp}/good.csv --out {tmp}/o --size-prior 0.1:0.01", "--size-prior"),
    ("fit {tmp}/good.csv --out {tmp}/o --size-prior 0.0001:0.01", "size prior"),
    ("fit {tmp}/good.csv --out {tmp}/o --ffd 1x1x1", "--ffd"),
    ("fit {tmp}/good.csv --out {tmp}/o --ffd-tau 5", "--ffd-tau"),
    # sizes whose memory or time grows with them have a stated limit (were MemoryError / OOM, issue 24)
    ("fit {tmp}/good.csv --out {tmp}/o --walkers 1000000000", "--walkers"),
    ("fit {tmp}/good.csv --out {tmp}/o --ffd 20x20x20", "--ffd"),
    ("explore --object {egg} --draws 1000000000 --out {tmp}/o", "--draws"),
    ("explore --object {egg} --candidates 1000000000 --out {tmp}/o", "--candidates"),
    ("explore --object {egg} --strokes 100000 --out {tmp}/o", "--strokes"),
    ("explore --object {egg} --draws 1 --out {tmp}/o", "--draws"),
    # issue 24, ninth review: a centre in millimetres or centimetres sent strokes metres away
    (
        "explore --port /dev/null --centre 0,0,5 --out {tmp}/o",
        "0,0,5: the coordinates look like centimetres or millimetres (largest |value| 5.0); give",
    ),
    ("explore --object {egg} --target-volume-sd -1 --out {tmp}/o", "--target-volume-sd"),
    ("experiment --strokes 100000 --out {tmp}/o", "--strokes"),
    ("experiment --draws 1 --out {tmp}/o", "--draws"),
    ("sbc --datasets 1000000000 --out {tmp}/o", "--datasets"),
    ("device run --port {tmp}/no_such_port --strokes 1000000000 --out {tmp}/r.nc", "--strokes"),
    ("device run --port {tmp}/no_such_port --strokes 1 --journal {tmp}/keep.txt --out {tmp}/r.nc", "--journal"),
    ("simulate --object {tmp}/negative_amplitude.toml --out {tmp}/r.nc", "amplitude_m"),
    ("simulate --object {tmp}/negative_roughness.toml --out {tmp}/r.nc", "roughness_m"),
    ("fit {tmp}/good.csv --out {tmp}/o --nu -2", "--nu"),
    # issue 24, ninth review: ν = 1e300 or 1e-300 overflowed to an exit 1 after JAX warnings
    ("fit {tmp}/good.csv --out {tmp}/o --noise student --nu 1e300", "--nu must be in [0.5, 1000]"),
    ("fit {tmp}/good.csv --out {tmp}/o --noise student --nu 1e-300", "--nu must be in [0.5, 1000]"),
    ("fit {tmp}/good.csv --out {tmp}/o --noise student --nu nan", "--nu must be in [0.5, 1000]"),
    ("fit {tmp}/good.csv --out {tmp}/o --steps 0", "--steps"),
    ("fit {tmp}/good.csv --out {tmp}/o --noise laplace", "--noise"),
    ("fit {tmp}/good.csv --out {tmp}/o --precision half", "--precision"),
    ("fit {tmp}/good.csv --out {tmp}/o --precision mixed --noise mixture", "precision"),
    ("fit {tmp}/good.csv --out {tmp}/o --texture on", "--texture"),
    ("fit {tmp}/good.csv --out {tmp}/o --stride 2", "--stride"),
    # --lag is a recording's option whichever value is given, the default one included
    ("fit {tmp}/good.csv --out {tmp}/o --lag known", "--lag"),
    ("fit {tmp}/good.csv --out {tmp}/o --lag sampled", "--lag"),
    ("fit {tmp}/good.csv --out {tmp}/o --lag maybe", "--lag"),
    ("fit {tmp}/good.csv --out {tmp}/o --texture maybe", "--texture"),
    ("fit {tmp}/good.csv --out {tmp}/o --stride 0", "--stride"),
    ("reproduce-paper --out {tmp}/o --sizes 6x6", "6x6x3"),
    ("reproduce-paper --out {tmp}/o --epsilons 0.7", "[0, 0.5)"),
    ("reproduce-paper --out {tmp}/o --rate -1", "--rate"),
    ("explore --object {egg} --planner clever --out {tmp}/o", "clever"),
    ("explore --object {egg} --budget 0 --out {tmp}/o", "--budget"),
    ("explore --object {egg} --candidates 0 --out {tmp}/o", "--candidates"),
    ("experiment --planners eig,clever --out {tmp}/o", "clever"),
    ("experiment --trials 0 --out {tmp}/o", "--trials"),
    ("experiment --objects teapot --out {tmp}/o", "teapot"),
    ("experiment --scheduler nonsense --out {tmp}/o", "--scheduler"),
    ("explore --object {egg} --carrier --out {tmp}/o", "--carrier applies to a finger"),
    ("experiment --carrier --out {tmp}/o", "carrier strokes run on a finger"),
    ("experiment --prober finger --carrier --pose-draws 4 --out {tmp}/o", "no pose-error law"),
    ("experiment --trials 1000000000 --out {tmp}/o", "split it"),
    ("experiment --scheduler tcp://127.0.0.1:9 --budget 1 --trials 1 --out {tmp}/o", "no Dask scheduler"),
    ("device simulate --drop 2", "--drop"),
    # issue 24, ninth review: the pty's status line came before the error (two lines)
    ("device simulate --object BAD", "unknown object 'BAD'"),
    ("device run --port {tmp}/no_such_port --strokes 0 --out {tmp}/r.nc", "--strokes"),
    ("demo --seed -1 --out {tmp}/o", "--seed"),
    # seeds outside NumPy's [0, 2**32) are refused before any work, in every command that takes one
    ("fit {tmp}/good.csv --out {tmp}/o --seed -1", "--seed"),
    ("fit {tmp}/good.csv --out {tmp}/o --seed 4294967296", "2**32"),
    ("explore --object {egg} --seed -3 --out {tmp}/o", "--seed"),
    ("simulate --object {egg} --seed 99999999999 --out {tmp}/s.nc", "--seed"),
    ("texture-id --seed -1 --out {tmp}/o", "--seed"),
    ("device simulate --seed -2", "--seed"),
    ("texture-id --textures 99 --out {tmp}/o", "--textures"),
    ("texture-id --trials 0 --out {tmp}/o", "--trials"),
    ("texture-id --library {tmp}/broken.toml --out {tmp}/o", "broken.toml"),
    ("texture-id --calibration {tmp}/no_device.toml --out {tmp}/o", "no_device.toml"),
    ("nonsense", "nonsense"),
    # an output path that is a file already: refused, and the file is kept
    ("fit {tmp}/good.csv --out {tmp}/keep.txt", "keep.txt"),
    ("demo --out {tmp}/keep.txt", "keep.txt"),
    ("demo --out {tmp}/a_fit_run", "not a demo's"),
    ("fit {tmp}/a_fit_run --out {tmp}/o", "is a folder"),
    ("fit /dev/null --out {tmp}/o", "not a regular file"),
    ("fit {tmp}/good.csv --out {tmp}/damaged_run --resume", "damaged"),
    ("explore --object {egg} --out {tmp}/keep.txt", "keep.txt"),
    ("simulate --object {egg} --out {tmp}/folder.nc", "folder"),
    # output paths that cannot be written (review of issue 24, second round)
    ("fit {tmp}/good.csv --out {tmp}/loop_a", "symbolic link to nothing"),
    ("fit {tmp}/good.csv --out {tmp}/dangling", "symbolic link to nothing"),
    ("fit {tmp}/good.csv --out {tmp}/keep.txt/run", "is not a folder"),
    ("simulate --object {egg} --out {tmp}/keep.txt/r.nc", "is not a folder"),
    ("simulate --object {egg} --out /proc/r.nc", "cannot create files in /proc"),
    # object and texture files whose tables have the wrong type, unknown keys or absurd sizes
    ("simulate --object {tmp}/defects_int.toml --out {tmp}/r.nc", "'defects' must be tables [[defects]]"),
    ("simulate --object {tmp}/texture_int.toml --out {tmp}/r.nc", "must be a table [texture]"),
    ("explore --object {tmp}/object_str.toml --out {tmp}/o", "must be a table [object]"),
    ("simulate --object {tmp}/typo.toml --out {tmp}/r.nc", "unknown key 'angle_rad'"),
    ("simulate --object {tmp}/textures_typo.toml --out {tmp}/r.nc", "unknown key 'textures'"),
    ("simulate --object {tmp}/deep_defect.toml --out {tmp}/r.nc", "'depth_m' must not exceed"),
    ("simulate --object {tmp}/ffd_huge.toml --out {tmp}/r.nc", "'dims' must be three integers from 2 to 16"),
    ("simulate --object {tmp}/ffd_amp.toml --out {tmp}/r.nc", "must stay below a fifth"),
    ("simulate --object {tmp}/far.toml --out {tmp}/r.nc", "beyond ±2 m"),
    ("simulate --object {tmp}/micro.toml --out {tmp}/r.nc", "below 1 mm"),
    ("texture-id --library {tmp}/lib_ints.toml --out {tmp}/o", "expected a table [[texture]]"),
    # a netCDF file that is not a recording, and a device file with an absurd response scale
    ("calibrate {tmp}/posterior_like.nc --object sphere --out {tmp}/d.toml", "variable 'taxel_current' is missing"),
    ("fit {sphere_rec} --out {tmp}/o --calibration {tmp}/huge_scale.toml", "[response] scale must be a number in"),
    ("fit {tmp}/UPPER.NC --out {tmp}/o", "variable 'taxel_current' is missing"),  # read as a recording, not a CSV
    ("simulate --object {egg} --duration 1e-9 --out {tmp}/r.nc", "fewer than 2 frames per stroke"),
    ("device run --port {tmp}/no_such_port --strokes 1 --out {tmp}/d.nc --journal {tmp}/d.nc", "is the --out"),
    # negative numbers in scientific notation, or lists starting with one, are values ("expected one argument")
    ("simulate --object {egg} --depth -1e-4 --out {tmp}/r.nc", "--depth: each pressing depth must be in"),
    ("simulate --object {egg} --currents -0.15,0.05,0.05 --out {tmp}/r.nc", "wire currents must each be in"),
    # flags that contradict each other (one was silently ignored)
    ("simulate --object {egg} --force 0.07 --depth 3e-4 --out {tmp}/r.nc", "--depth and --force exclude each other"),
    ("experiment --resume --overwrite --trials 1 --out {tmp}/o", "--resume and --overwrite exclude each other"),
    ("sbc --area-term --no-area-term --out {tmp}/o", "--area-term and --no-area-term exclude each other"),
    ("explore --object {egg} --timeout 5 --out {tmp}/o", "--timeout applies to a finger on --port"),
    # experiment lists: empty or repeated entries (an empty --objects ran nothing, exit 0; eig,eig doubled rows)
    ("experiment --objects , --out {tmp}/o", "--objects: expected comma-separated"),
    ("experiment --planners eig,eig --trials 1 --out {tmp}/o", "--planners: eig named twice"),
    ("experiment --objects egg,sphere,egg --trials 1 --out {tmp}/o", "--objects: egg named twice"),
    # contact files: repeated rows, values near the float limit, an object beyond the prior's sizes
    ("fit {tmp}/two_points_repeated.csv --out {tmp}/o", "only 2 distinct points among 60"),
    ("fit {tmp}/near_float_max.csv --out {tmp}/o", "look like some unit other than metres"),
    ("fit {tmp}/big_ball.csv --out {tmp}/o", "more than twice the prior's largest semi-axis"),
    # third review (issue 24): exactly flat contacts (emcee stopped on an infinite proposal, exit 1)
    ("fit {tmp}/coplanar.csv --out {tmp}/o", "the contacts lie in one plane"),
    # a dead read-out fitted to a confident posterior, exit 0; calibrated to a device file fit then refused
    ("fit {tmp}/dead_readout.nc --out {tmp}/o", "'taxel_current' never changes"),
    ("calibrate {tmp}/dead_readout.nc --object sphere --out {tmp}/d.toml", "'taxel_current' never changes"),
    ("calibrate {tmp}/quantum_mode.nc --object sphere --out {tmp}/d.toml", "attribute 'mode' is 'quantum'"),
    ("calibrate {sphere_rec} --object box --out {tmp}/d.toml", "recorded over 'sphere', not 'box'"),
    ("fit {sphere_rec} --calibration {tmp}/zero_noise.toml --out {tmp}/o", "noise_scale must be a finite number > 0"),
    # ports that are no serial device (exit 1, an empty journal and a folder left behind)
    ("device run --port {tmp} --strokes 1 --out {tmp}/p/r.nc", "is a folder, not a serial device"),
    ("device run --port {tmp}/keep.txt --strokes 1 --out {tmp}/p/r.nc", "is a plain file, not a serial device"),
    ("device run --port {tmp}/fifo --strokes 1 --out {tmp}/p/r.nc", "is a FIFO, not a serial device"),
    ("device run --port loop:// --strokes 1 --out {tmp}/p/r.nc", "sends back every packet written to it"),
    ("device run --port socket://127.0.0.1:9 --strokes 1 --out {tmp}/p/r.nc", "cannot open the port"),
    # stroke files: a misspelt key left the default currents in place; huge numbers and deep nesting were exit 1
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/typo_strokes.json --out {tmp}/r.nc", "'hold_current'"),
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/huge_depth.json --out {tmp}/r.nc", "needs numeric"),
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/deep.json --out {tmp}/r.nc", "cannot be read as JSON"),
    ("device run --port {tmp}/no_such_port --stroke-file {tmp}/extra_top.json --out {tmp}/r.nc", "unknown key(s)"),
    # fourth review: a command wrote over another command's results (a fit's summary.json), or over its own
    ("texture-id --out {tmp}/a_fit_run --textures 2 --trials 1 --max-strokes 1", "already holds summary.json"),
    ("sbc --datasets 2 --out {tmp}/a_fit_run", "already holds summary.json"),
    ("reproduce-paper --paths 1 --sizes 2x2x2 --out {tmp}/a_fit_run", "already holds summary.json"),
    ("explore --strokes 1 --out {tmp}/has_points", "already holds results (points.csv)"),
    ("texture-id --out {tmp}/t --max-strokes 100000000", "--max-strokes"),
    ("texture-id --out {tmp}/t --trials 100000000", "--trials"),
    ("reproduce-paper --sizes , --out {tmp}/p2", "--sizes"),
    ("reproduce-paper --epsilons , --out {tmp}/p2", "--epsilons"),
    # a run without its run.json continued with other data (the old object's volume, exit 0)
    ("fit {tmp}/good.csv --out {tmp}/a_fit_run --resume", "but no run.json"),
    ("experiment --objects sphere,{sphere} --trials 1 --out {tmp}/x", "are the same object file"),
    # options that do not apply were dropped without a word
    ("explore --planner random --per-second --out {tmp}/e", "--per-second applies to the eig planner"),
    ("device run --port {tmp}/no_such_port --duration 0.5 --rate 1 --out {tmp}/r.nc", "gives fewer than 2 frames"),
    ("explore --draws 1 --out {tmp}/e", "--draws must be an integer from 10 to"),
    ("explore --draws 0 --out {tmp}/e", "--draws must be an integer from 10 to"),
    ("fit {sphere_rec} --out {tmp}/o --texture off --noise student --nu 3", "--noise, --nu: apply to contact points"),
    ("fit {sphere_rec} --out {tmp}/o --precision mixed", "--precision: apply to contact points"),
    ("fit {tmp}/good.csv --out {tmp}/o --ffd-tau 1e-3", "--ffd-tau goes with --ffd"),
    ("calibrate {tmp}/interleaved.nc --object sphere --out {tmp}/d.toml", "comes back after other strokes"),
    (
        "device run --port {tmp}/no_such_port --stroke-file {tmp}/typo_strokes.json --depth 1e-4 --out {tmp}/r.nc",
        "--depth: not used with --stroke-file",
    ),
]


def _files(tmp):
    (tmp / "no_header.csv").write_text("0.01,0.02,0.03\n0.02,0.01,0.0\n")
    (tmp / "wrong_columns.csv").write_text("a,b,c\n0.01,0.02,0.03\n")
    (tmp / "text_values.csv").write_text("x,y,z\n0.01,abc,0.03\n")
    (tmp / "nan_values.csv").write_text("x,y,z\n0.01,nan,0.03\n" * 20)
    (tmp / "empty.csv").write_text("x,y,z\n")
    (tmp / "millimetres.csv").write_text(
        "x,y,z\n"
        + "".join(
            f"{30 * c:.3f},{20 * s:.3f},5.0\n" for c, s in zip([1, 0, -1, 0] * 10, [0, 1, 0, -1] * 10, strict=True)
        )
    )
    turn = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    (tmp / "good.csv").write_text(
        "x,y,z\n"
        + "".join(f"{0.03 * np.cos(t):.5f},{0.02 * np.sin(t):.5f},{0.005 * np.sin(2 * t):.5f}\n" for t in turn)
    )
    d = np.random.default_rng(0).normal(size=(50_001, 3))
    np.savetxt(
        tmp / "huge.csv",
        0.03 * d / np.linalg.norm(d, axis=1, keepdims=True),
        delimiter=",",
        header="x,y,z",
        comments="",
        fmt="%.6f",
    )
    np.savetxt(
        tmp / "micrometres.csv",
        3e-5 * d[:80] / np.linalg.norm(d[:80], axis=1, keepdims=True),
        delimiter=",",
        header="x,y,z",
        comments="",
    )
    (tmp / "not_a_recording.nc").write_bytes(b"this is not netCDF")
    (tmp / "no_shape.toml").write_text('[object]\nname = "x"\n')
    (tmp / "broken.toml").write_text("[shape\ncentre_m = [0, 0\n")
    (tmp / "millimetres.toml").write_text("[shape]\ncentre_m = [0, 0, 0]\naxes_m = [45, 25, 5]\nn = 10\n")
    (tmp / "negative_axes.toml").write_text("[shape]\ncentre_m = [0, 0, 0]\naxes_m = [0.03, -0.02, 0.02]\nn = 2\n")
    (tmp / "nan_axes.toml").write_text("[shape]\ncentre_m = [0, 0, 0]\naxes_m = [0.03, nan, 0.02]\nn = 2\n")
    (tmp / "huge_n.toml").write_text("[shape]\ncentre_m = [0, 0, 0]\naxes_m = [0.03, 0.02, 0.02]\nn = 3000\n")
    shape = "[shape]\ncentre_m = [0, 0, 0]\naxes_m = [0.03, 0.02, 0.02]\nn = 2\n"
    (tmp / "negative_modes.toml").write_text(shape + "[texture]\nwavelength_m = 0.002\nmodes = -5\n")
    (tmp / "negative_seed.toml").write_text(shape + "[texture]\nwavelength_m = 0.002\nseed = -1\n")
    (tmp / "negative_amplitude.toml").write_text(shape + "[texture]\nwavelength_m = 0.002\namplitude_m = -0.01\n")
    (tmp / "negative_roughness.toml").write_text(shape + "[texture]\nwavelength_m = 0.002\nroughness_m = -1e-5\n")
    (tmp / "bad_strokes.json").write_text('{"strokes": [{"contact": [[0, 0]]}]}')
    (tmp / "keep.txt").write_text("recorded")
    (tmp / "a_fit_run").mkdir()
    (tmp / "a_fit_run" / "summary.json").write_text("{}")
    (tmp / "damaged_run").mkdir()
    (tmp / "damaged_run" / "summary.json").write_text("{}")
    (tmp / "damaged_run" / "run.json").write_text("{not json")
    (tmp / "folder.nc").mkdir()
    (tmp / "defects_int.toml").write_text("defects = 5\n" + shape)
    (tmp / "texture_int.toml").write_text("texture = 5\n" + shape)
    (tmp / "object_str.toml").write_text('object = "egg"\n' + shape)
    (tmp / "typo.toml").write_text(shape + "angle_rad = [0.4, 0.3, -0.5]\n")
    (tmp / "textures_typo.toml").write_text(shape + "[textures]\nwavelength_m = 0.002\n")
    bump = '[[defects]]\nkind = "bump"\ncentre_m = [0.03, 0, 0]\nradius_m = 0.002\n'
    (tmp / "deep_defect.toml").write_text(shape + bump + "depth_m = 5.0\n")
    (tmp / "ffd_huge.toml").write_text(shape + "[ffd]\ndims = [1000, 1000, 1000]\n")
    (tmp / "ffd_amp.toml").write_text(shape + "[ffd]\ndims = [3, 3, 3]\namplitude_m = 0.5\n")
    (tmp / "far.toml").write_text(shape.replace("centre_m = [0, 0, 0]", "centre_m = [100, 0, 0]"))
    (tmp / "micro.toml").write_text(shape.replace("[0.03, 0.02, 0.02]", "[1e-6, 1e-6, 1e-6]"))
    lib = (MODELS / "textures.toml").read_text()
    (tmp / "lib_ints.toml").write_text("texture = [1, 2]\n" + lib[lib.index("[library]") : lib.index("[[texture]]")])
    xr.Dataset({"volume": ("draw", np.ones(4))}).to_netcdf(tmp / "posterior_like.nc", engine="h5netcdf")
    (tmp / "two_points_repeated.csv").write_text("x,y,z\n" + "0.01,0.02,0.03\n0.02,0.01,0.0\n" * 30)
    (tmp / "near_float_max.csv").write_text("x,y,z\n" + "".join(f"{v},1e308,-1e308\n" for v in range(20)))
    ring = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    (tmp / "big_ball.csv").write_text(
        "x,y,z\n" + "".join(f"{0.4 * np.cos(t)},{0.4 * np.sin(t)},{0.01 * np.sin(3 * t)}\n" for t in ring)
    )
    (tmp / "UPPER.NC").write_bytes((tmp / "posterior_like.nc").read_bytes())
    cal = DeviceCalibration(np.zeros(256), np.full(256, 1e-3), 1.0, "physics", {}, 2.0, 1e-3)
    write_device_file(tmp / "huge_scale.toml", cal)  # then damaged: write_device_file refuses such values itself
    text = (tmp / "huge_scale.toml").read_text()
    (tmp / "huge_scale.toml").write_text(
        text.replace("scale = 2.0", "scale = 1e300").replace("_sd = 0.001", "_sd = 1e-300")
    )
    (tmp / "zero_noise.toml").write_text(text.replace("noise_scale = 1.0", "noise_scale = 0.0"))
    d = np.random.default_rng(2).normal(size=(60, 2))
    (tmp / "coplanar.csv").write_text("x,y,z\n" + "".join(f"{0.02 * a},{0.02 * b},0.01\n" for a, b in d))
    rec = xr.open_dataset(MODELS.parent / "data" / "recordings" / "sphere.nc").load()
    rec.assign(taxel_current=rec.taxel_current * 0).to_netcdf(tmp / "dead_readout.nc", engine="h5netcdf")
    rec.assign_attrs(mode="quantum").to_netcdf(tmp / "quantum_mode.nc", engine="h5netcdf")
    os.mkfifo(tmp / "fifo")
    (tmp / "has_points").mkdir()
    (tmp / "has_points" / "points.csv").write_text("x,y,z\n0,0,0\n")
    k = rec.stroke_index.values.copy()
    k[::2] = 0  # stroke 0's frames interleaved with the others'
    rec.assign_coords(stroke_index=("frame", k)).to_netcdf(tmp / "interleaved.nc", engine="h5netcdf")
    one = '{"time": [0, 0.02], "contact": [[0, 0, 0.02], [0, 2e-4, 0.02]], "normal": [[0, 0, 1], [0, 0, 1]], '
    (tmp / "typo_strokes.json").write_text('{"strokes": [' + one + '"depth": 3e-4, "hold_current": [0, 0, 0]}]}')
    (tmp / "huge_depth.json").write_text('{"strokes": [' + one + '"depth": 1' + "0" * 400 + "}]}")
    (tmp / "deep.json").write_text('{"strokes": ' + "[" * 100_000 + "]" * 100_000 + "}")
    (tmp / "extra_top.json").write_text('{"strokes": [' + one + '"depth": 3e-4}], "speed": 5}')
    (tmp / "loop_a").symlink_to(tmp / "loop_b")
    (tmp / "loop_b").symlink_to(tmp / "loop_a")
    (tmp / "dangling").symlink_to(tmp / "nowhere")


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    t = tmp_path_factory.mktemp("bad_input")
    _files(t)
    return t


@pytest.mark.parametrize("line,needle", TABLE, ids=[row[0].split(" {")[0] + f"#{i}" for i, row in enumerate(TABLE)])
def test_bad_input_one_line_exit_2(line, needle, tmp, capsys):
    from bayestouch.params import MODELS

    argv = line.format(
        tmp=tmp,
        egg=MODELS / "objects" / "egg.toml",
        sphere=MODELS / "objects" / "sphere.toml",
        sphere_rec=MODELS.parent / "data" / "recordings" / "sphere.nc",
    ).split()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own errors
        code = e.code
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2, (code, err)
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert needle in lines[0], lines[0]
    assert (tmp / "keep.txt").read_text() == "recorded"
    assert not (tmp / "p").exists()  # a refused port leaves no folder or journal behind


def test_an_empty_out_path_is_refused(tmp_path, capsys, monkeypatch):
    """``--out ''`` once wrote a fit into the current folder (issue 24): every command refuses it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "good.csv").write_text(
        "x,y,z\n" + "".join(f"{0.03 * c:.4f},{0.02 * (1 - c)},0.0\n" for c in (0, 1) * 20)
    )
    for argv in (["fit", "good.csv", "--out", ""], ["simulate", "--object", "egg", "--out", " "]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert "--out" in err and "empty path" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.csv"]


def test_python_m_bayestouch_is_the_command_line():
    """``python -m bayestouch`` runs the CLI (it had no __main__: 'is a package and cannot be directly executed')."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "bayestouch", "fit", "/no/such.csv", "--out", "x"], capture_output=True)
    assert r.returncode == 2 and b"no such file" in r.stderr
