"""The notebook API, one verb per job: :func:`fit` returns a :class:`Fit`, an object over a run folder that holds the
posterior as ArviZ ``InferenceData``, its summary as a table with units, its meshes as trimesh objects and a picture;
:func:`simulate` returns a recording (``xarray.Dataset``); :func:`calibrate` a device file's contents;
:func:`bayestouch.explore` (in :mod:`bayestouch.planning.loop`) an exploration's record. The commands
``bayestouch fit``, ``simulate`` and ``calibrate`` call these.

``bayestouch fit`` is this function on the command line. A fit with no ``out`` folder runs in a temporary folder
that lives as long as its :class:`Fit` (``fit.save(folder)`` keeps it); :meth:`Fit.load` opens a folder written
earlier, by the API or the CLI.

Library code logs to ``logging.getLogger("bayestouch")`` and never switches the matplotlib backend: :meth:`Fit.plot`
draws with whatever backend the notebook uses.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np

from bayestouch.errors import BadInput, check_bool, check_bools, check_int, check_seed, file_problem, shown
from bayestouch.io.contacts import (
    N_ELLIPSOID_PARAMS,
    ContactPoints,
    check_contact_spread,
    contact_points_from_table,
    load_contact_points,
)
from bayestouch.io.files import atomic_path, set_aside
from bayestouch.io.runfolder import OUTPUTS, every_earlier_file, locked_run_folder
from bayestouch.params import MODELS

__all__ = ["Fit", "fit", "simulate", "calibrate"]

#: contact-level options of :func:`fit` (keyword: meaning), passed to
#: :func:`bayestouch.inference.run.run_contact_fit`
_CONTACT_OPTIONS = ("noise", "nu", "normals", "free", "ffd", "ffd_tau", "size_prior", "init", "precision")
#: recording options, passed to :func:`bayestouch.inference.raw.run_raw_fit`
_RAW_OPTIONS = ("texture", "stride", "calibration", "lag")


class Fit:
    """A finished (or budget-stopped) shape fit: the run folder's files as Python objects, loaded on first use.

    Attributes
    ----------
    folder : Path
        The run folder (a temporary one, removed with this object, for ``fit(..., out=None)``).
    results : dict
        ``summary.json``: parameters, derived quantities (SI units in their names), diagnostics, model.
    """

    def __init__(self, folder, *, _temporary: tempfile.TemporaryDirectory | None = None):
        self.folder = _folder_path(folder, "folder")
        path = self.folder / "summary.json"
        if not path.is_file():
            raise BadInput(f"{self.folder}: no summary.json (expected the folder of a finished `bayestouch fit`)")
        try:
            self.results = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise BadInput(f"{path}: cannot be read as JSON ({type(e).__name__}); a damaged summary") from None
        r = self.results if isinstance(self.results, dict) else {}
        missing = [k for k in ("derived", "diagnostics", "model") if not isinstance(r.get(k), dict)]
        if missing:
            raise BadInput(
                f"{path}: not the summary of a fit (no {', '.join(missing) or 'object'}); expected the summary.json "
                "of `bayestouch fit`"
            )
        self._temporary = _temporary
        self._idata = None
        if _temporary is not None:  # the temporary folder goes with the object
            weakref.finalize(self, _temporary.cleanup)

    @classmethod
    def load(cls, folder) -> Fit:
        """Open the run folder ``folder`` written by :func:`fit` or ``bayestouch fit``."""
        return cls(folder)

    def __repr__(self) -> str:
        v = self.results["derived"]["volume_m3"]
        d = self.results["diagnostics"]
        state = "converged" if d["converged"] else "NOT converged"
        if d.get("multimodal"):
            state += f", MULTIMODAL ({len(d['modes'])} shapes)"
        if d.get("misfit"):
            state += ", MISFIT"
        if d.get("noise_large"):
            state += ", NOISE ~ SIZE"
        if d.get("extrapolated"):
            state += ", EXTRAPOLATED"
        return (
            f"<bayestouch.Fit {self.results['model'].get('level', '?')} level: volume {v['mean'] * 1e6:.3f} ± "
            f"{v['sd'] * 1e6:.3f} cm³, {state}, {len(self.warnings)} warning(s); {self.folder}>"
        )

    @property
    def converged(self) -> bool:
        """Whether the chain passed its convergence checks (R-hat, bulk ESS, chain length over τ)."""
        return bool(self.results["diagnostics"]["converged"])

    @property
    def multimodal(self) -> bool:
        """Whether the posterior holds separated shapes (``results["diagnostics"]["modes"]`` describes them)."""
        return bool(self.results["diagnostics"].get("multimodal", False))

    @property
    def misfit(self) -> bool:
        """Whether the shape leaves structure in the contacts' residuals rather than noise (a mode that is not the
        data's, or an object outside the model's family; ``results["diagnostics"]["residual_neighbour_correlation"]``
        holds the statistic, ``docs/contact_model.md`` the method). False where the check does not apply."""
        return bool(self.results["diagnostics"].get("misfit", False))

    @property
    def noise_large(self) -> bool:
        """Whether the noise scale σ is above 5 % of the smallest semi-axis (posterior medians), where the distance
        likelihood's intervals are too narrow (``docs/sbc.md``). False where the check does not apply."""
        return bool(self.results["diagnostics"].get("noise_large", False))

    @property
    def extrapolated(self) -> bool:
        """Whether the surface runs farther from every contact than 1.5 times the contacts' span (posterior median,
        ``results["diagnostics"]["reach"]``): there the shape is the model family's extension of the touched part,
        right only if the object belongs to the family (``docs/contact_model.md``, "Extrapolation"). False where
        the check does not apply."""
        return bool(self.results["diagnostics"].get("extrapolated", False))

    @property
    def warnings(self) -> list[str]:
        """The fit's warnings about itself (misfit, prior-dominated axes, …), as on the command line."""
        return list(self.results["diagnostics"].get("warnings", []))

    @property
    def idata(self):
        """The posterior as ArviZ ``InferenceData`` (``posterior.nc``, read into memory on first use)."""
        if self._idata is None:
            import arviz as az

            path = self.folder / "posterior.nc"
            if not path.is_file():
                raise BadInput(f"{path}: no such file (an interrupted fit writes it when continued with --resume)")
            try:
                with az.rc_context({"data.load": "eager"}):
                    self._idata = az.from_netcdf(str(path))
            except (OSError, ValueError, KeyError) as e:  # truncated or not netCDF
                raise BadInput(
                    f"{path}: cannot be read as the posterior ({type(e).__name__}); a damaged file"
                ) from None
            if "posterior" not in self._idata.groups():  # valid netCDF of something else (e.g. a recording)
                groups = ", ".join(self._idata.groups()) or "none"
                self._idata = None
                raise BadInput(
                    f"{path}: no posterior group (groups: {groups}); expected the ArviZ posterior.nc that "
                    "`bayestouch fit` writes"
                )
        return self._idata

    def summary(self):
        """The posterior summary as a ``pandas.DataFrame``: one row per parameter and derived quantity, columns
        ``mean, sd, q05, q95`` (in the row's SI ``unit``), ``r_hat`` and ``ess_bulk`` (NaN where not computed)."""
        import pandas as pd

        units = {name: self.idata.posterior[name].attrs.get("units", "") for name in self.idata.posterior.data_vars}
        rows = {}
        for name, p in self.results["parameters"].items():
            rows[name] = {
                **{k: p[k] for k in ("mean", "sd", "q05", "q95", "r_hat", "ess_bulk")},
                "unit": units.get(name, ""),
            }
        derived = self.results["derived"]
        for key, label, unit in (("volume_m3", "volume", "m3"), ("area_m2", "area", "m2")):
            rows[label] = {**{k: derived[key][k] for k in ("mean", "sd", "q05", "q95")}, "unit": unit}
        for i in range(3):
            rows[f"inertia[{i}]"] = {
                **{k: derived["inertia_principal_m5"][k][i] for k in ("mean", "sd", "q05", "q95")},
                "unit": "m5",
            }
        table = pd.DataFrame.from_dict(rows, orient="index")
        table.index.name = "quantity"
        return table[["mean", "sd", "q05", "q95", "unit", "r_hat", "ess_bulk"]]

    def mesh(self):
        """The posterior-mean surface as a ``trimesh.Trimesh`` (metres)."""
        import trimesh

        return trimesh.load(self.folder / "mean_shape.ply", process=False)

    def uncertainty_mesh(self):
        """The mean surface coloured by the posterior spread of the surface along its normal; the spread (m) per
        vertex is in ``vertex_attributes["spread"]``."""
        from bayestouch.io.meshes import read_spread_mesh

        return read_spread_mesh(self.folder / "uncertainty_mesh.ply")

    def loo(self, **kwargs):
        """PSIS-LOO (``az.loo``) of the contact or frame log-likelihood, with ``reff = 1``: the log-likelihood
        group holds thinned, nearly independent draws, not the whole chain that ArviZ would take ``reff`` from."""
        import arviz as az

        kwargs.setdefault("reff", 1.0)
        return az.loo(self.idata, **kwargs)

    def loo_pit(self):
        """LOO-PIT values (``az.loo_pit``) of each contact's distance from the contacts' centroid (``radius``):
        uniform on [0, 1] when the residual model is right (contact level only)."""
        import arviz as az

        idata = self.idata
        if "radius" not in idata.observed_data:
            raise BadInput("loo_pit: this fit has no per-contact observable (a recording's fit: use loo)")
        ll = idata.log_likelihood["points"].stack(__sample__=("chain", "draw"))
        log_weights = az.psislw(-ll, reff=1.0)[0]
        y_hat = idata.posterior_predictive["radius"].stack(__sample__=("chain", "draw"))
        return az.loo_pit(y=idata.observed_data["radius"], y_hat=y_hat, log_weights=log_weights)

    def plot(self, *, points=None, figure=None):
        """The mean surface coloured by its spread (mm) with the contacts, and the volume's posterior.

        Parameters
        ----------
        points : (M, 3) float, metres, optional
            Contacts to draw (default: the observed contacts of a contact-level fit).
        figure : matplotlib Figure, optional
            Draw into this figure (default: a new ``pyplot`` figure, shown by the notebook's own backend).

        Returns
        -------
        matplotlib Figure
        """
        if figure is None:
            import matplotlib.pyplot as plt

            figure = plt.figure(figsize=(10, 4.5), constrained_layout=True)
        um = self.uncertainty_mesh()
        spread = np.asarray(um.vertex_attributes["spread"], float)
        v = np.asarray(um.vertices) * 1e3
        ax = figure.add_subplot(1, 2, 1, projection="3d")
        faces = np.asarray(um.faces)
        coll = ax.plot_trisurf(v[:, 0], v[:, 1], v[:, 2], triangles=faces, cmap="viridis", linewidth=0, alpha=0.85)
        coll.set_array(spread[faces].mean(axis=1) * 1e3)
        figure.colorbar(coll, ax=ax, shrink=0.7, label="surface spread (mm)")
        if points is None and "points" in self.idata.observed_data:
            points = self.idata.observed_data["points"].values
        if points is not None:
            p = np.asarray(points, float) * 1e3
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=4, color="k", depthshade=False)
        ax.set(xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)", title="mean surface, coloured by spread")
        ax.set_box_aspect(np.ptp(v, axis=0))
        ax2 = figure.add_subplot(1, 2, 2)
        vol = np.asarray(self.idata.posterior["volume"].values).ravel() * 1e6
        ax2.hist(vol, bins=60, color="C0", alpha=0.8)
        q05, q95 = np.quantile(vol, [0.05, 0.95])
        for q in (q05, q95):
            ax2.axvline(q, color="k", ls="--", lw=0.8)
        ax2.set(xlabel="volume (cm³)", yticks=[], title=f"volume, 90 % interval {q05:.3f}–{q95:.3f} cm³")
        if not self.converged:
            figure.suptitle("NOT CONVERGED: the chain has not passed its checks", color="C3")
        elif self.misfit:
            figure.suptitle("MISFIT: the shape leaves structure in the residuals, not noise", color="C3")
        return figure

    def save(self, folder, *, overwrite: bool = False) -> Path:
        """Copy the run's files into ``folder`` (created).

        Parameters
        ----------
        folder : path
            The folder to write; one that already holds a run's files is refused unless ``overwrite``.
        overwrite : bool
            Replace the run in ``folder``: every file there (the earlier run's outputs and anything else beside
            them) is first moved into ``folder/replaced-<UTC time>/``, never deleted, and a line on stderr says
            where (as ``bayestouch fit --overwrite`` does), so no old file stays mixed with the new run.

        Returns
        -------
        pathlib.Path
            ``folder``.

        Raises
        ------
        BadInput
            ``folder`` is a file, or holds a run's files and ``overwrite`` is not given.
        """
        check_bool(overwrite, "overwrite")
        folder = _folder_path(folder, "folder")
        if folder.resolve() == self.folder.resolve():
            return folder
        if folder.exists() and not folder.is_dir():
            raise BadInput(f"save: {folder} exists and is not a folder")
        held = [f for f in OUTPUTS if (folder / f).exists()]
        if held and not overwrite:
            raise BadInput(
                f"save: {folder} already holds a run ({', '.join(held)}); pass overwrite=True to replace it (the "
                "earlier files are set aside), or choose another folder"
            )
        with locked_run_folder(folder):  # a run still writing there is refused, not moved from under it
            if overwrite:
                # set aside, not deleted: every file of the folder, so nothing of the earlier run (smc.npz, …) nor
                # any other old file stays beside the new one; folders (earlier replaced-*/, …) and the lock stay
                set_aside(every_earlier_file(folder), "Fit.save")
            # each file atomically, the summary last (a kill leaves no new summary beside old results)
            for name in sorted(OUTPUTS, key=lambda n: n == "summary.json"):
                src = self.folder / name
                if src.is_file():
                    with atomic_path(folder / name) as tmp:
                        shutil.copyfile(src, tmp)
        return folder


def _folder_path(folder, name: str) -> Path:
    """``folder`` as a Path, or a one-line refusal naming ``name`` when it is not a path (str or os.PathLike)."""
    if isinstance(folder, str | os.PathLike):
        text = os.fspath(folder)
        if isinstance(text, str):
            return Path(text)
    raise BadInput(f"{name}: expected a path (str or os.PathLike) of a run folder, got {shown(folder)}")


def _contacts(data) -> ContactPoints | None:
    """``data`` as contact points, or None for a recording (path ending .nc or an xarray Dataset)."""
    if isinstance(data, ContactPoints):
        return data
    if hasattr(data, "columns") and hasattr(data, "itertuples"):  # a pandas DataFrame: its columns by name
        return contact_points_from_table(data, "data")
    if isinstance(data, str | os.PathLike):
        path = Path(data)
        if path.suffix.lower() == ".nc":
            return None
        if problem := file_problem(path):
            raise BadInput(f"data: {path}: {problem} (expected a contact points CSV or a recording .nc)")
        return load_contact_points(path)
    if type(data).__name__ == "Dataset":  # an xarray recording
        return None
    try:
        a = np.asarray(data)
        complex_ = a.dtype.kind == "c"
        a = a if complex_ else a.astype(float)
    except (TypeError, ValueError):  # also a ragged nesting
        raise BadInput(
            f"data: expected contact points as an (M, 3) array of numbers in metres, got {type(data)}"
        ) from None
    if complex_:
        raise BadInput("data: the contact points are complex numbers; expected real coordinates in metres")
    if a.ndim != 2 or a.shape[1] != 3 or len(a) < N_ELLIPSOID_PARAMS:
        raise BadInput(
            f"data: expected contact points as an (M, 3) array in metres with M ≥ {N_ELLIPSOID_PARAMS} (as many as "
            f"the n-ellipsoid's parameters, the least a contact file holds), got shape {a.shape}"
        )
    if not np.isfinite(a).all():
        raise BadInput("data: the contact points hold NaN or infinite values (expected finite metres)")
    return ContactPoints(points=a, source="array")


def _sequence(value) -> list | None:
    """``value`` as a list when it is a list, tuple or 1-d array (its items unchecked), else None."""
    if isinstance(value, list | tuple) or (isinstance(value, np.ndarray) and value.ndim == 1):
        return list(value)
    return None


def _real(v) -> bool:
    """Whether ``v`` is a real number (not a bool)."""
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool | np.bool_)


def _size_prior(value) -> tuple[float, float]:
    """``size_prior`` as ``(min, max)`` metres: a pair of numbers or the command line's ``"MIN:MAX"``."""
    import argparse

    from bayestouch.cli.args import size_range

    if isinstance(value, str):
        try:
            return size_range(value)
        except argparse.ArgumentTypeError as e:
            raise BadInput(f"size_prior: {e}") from None
    pair = _sequence(value)
    if pair is None or len(pair) != 2 or not all(_real(v) for v in pair):
        raise BadInput(
            f"size_prior: expected (min, max) metres with 0 < min < max, or 'MIN:MAX' (e.g. (0.01, 0.1) or "
            f"'0.01:0.1' for objects 1-10 cm across), got {shown(value)}"
        )
    return float(pair[0]), float(pair[1])


def _ffd(value) -> tuple[int, int, int]:
    """``ffd`` as ``(l, m, k)`` control points: three integers or the command line's ``"LxMxK"``."""
    import argparse

    from bayestouch.cli.args import one_size
    from bayestouch.cli.fit import MAX_FFD_SIZE

    expected = f"expected (l, m, k) control points per axis, each an integer in [2, {MAX_FFD_SIZE}], or 'LxMxK'"
    if isinstance(value, str):
        try:
            size = one_size(value)
        except argparse.ArgumentTypeError as e:
            raise BadInput(f"ffd: {e}") from None
    else:
        size = tuple(_sequence(value) or ())
        ok = len(size) == 3 and all(isinstance(k, int | np.integer) and not isinstance(k, bool) for k in size)
        if not ok:
            raise BadInput(f"ffd: {expected} (e.g. (3, 3, 3) or '3x3x3'), got {shown(value)}")
    if not all(2 <= k <= MAX_FFD_SIZE for k in size):
        raise BadInput(f"ffd: {expected}, got {'x'.join(map(str, size))}")
    return tuple(int(k) for k in size)


def _check_seed(seed) -> None:
    check_seed(seed)


def fit(
    data,
    out=None,
    *,
    seed: int = 0,
    walkers: int = 32,
    steps: int | None = None,
    budget_s: float | str | None = "auto",
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    stop_when_converged: bool = True,
    **options,
) -> Fit:
    """Sample the shape posterior of contact points or of a recording's raw currents.

    Parameters
    ----------
    data : (M, 3) float array (metres), :class:`~bayestouch.io.contacts.ContactPoints`, table, path or xarray Dataset
        Contact points (an array, a ``ContactPoints`` with optional normals and free-space points, a table such as
        a pandas DataFrame with the CSV's named columns ``x, y, z[, nx, ny, nz][, force][, contact]``, or a CSV as
        ``bayestouch fit`` reads), or a recording (a ``.nc`` path or the ``xarray.Dataset`` of
        :func:`bayestouch.read_recording`).
    out : path, optional
        Run folder to write (refused when it holds a run, unless ``resume`` or ``overwrite``); default a temporary
        folder that lives as long as the returned :class:`Fit`.
    seed : int
        Seeds every random choice of the fit.
    walkers, steps : int
        emcee's ensemble size (even, ≥ 24) and the largest chain length (default 20000 steps for contacts, 1500 for
        a recording); sampling stops earlier once converged unless ``stop_when_converged=False``.
    budget_s : float, "auto" or None, seconds
        Wall-clock budget of the sampling (None: none; "auto": 60 s for contacts, none for a recording). A run
        stopped by it says so and is not converged; ``resume=True`` continues it.
    **options
        Contact level: ``noise``, ``nu``, ``normals`` (False ignores a file's normals),
        ``ffd`` ((l, m, k) control points or ``"LxMxK"``), ``ffd_tau`` (m), ``size_prior`` ((min, max) m or
        ``"MIN:MAX"``), ``free`` ((K, 3) m), ``init``, ``precision``
        (:func:`bayestouch.inference.run.run_contact_fit`). Recording: ``texture``, ``stride``, ``calibration``
        (a device file path or :class:`~bayestouch.io.device_file.DeviceCalibration`), ``lag`` ("sampled", the
        default, or "known"; :func:`bayestouch.inference.raw.run_raw_fit`).

    Returns
    -------
    Fit
    """
    check_bools(resume=resume, overwrite=overwrite, progress=progress, stop_when_converged=stop_when_converged)
    _check_seed(seed)
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int | np.integer) or steps < 1):
        raise BadInput(f"steps must be a positive integer (the largest chain length) or None, got {steps!r}")
    from bayestouch.inference.run import check_budget, check_walkers

    check_walkers(walkers)
    check_budget(budget_s, auto=True)
    cp = _contacts(data)
    if cp is not None:
        from bayestouch.inference.contact import load_priors

        check_contact_spread(cp.points, "data", load_priors().axis_max)
    allowed = _RAW_OPTIONS if cp is None else _CONTACT_OPTIONS
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        level = "a recording" if cp is None else "contact points"
        raise BadInput(
            f"fit: unknown option(s) {', '.join(unknown)} for {level} (expected any of {', '.join(allowed)})"
        )
    if cp is not None:  # the forms the command line parses, or one-line refusals naming the option
        if options.get("size_prior") is not None:
            options["size_prior"] = _size_prior(options["size_prior"])
        if options.get("ffd") is not None:
            options["ffd"] = _ffd(options["ffd"])
        if "free" in options:
            from bayestouch.inference.contact import check_free

            options["free"] = check_free(options["free"])
    temporary = None
    if out is None:
        temporary = tempfile.TemporaryDirectory(prefix="bayestouch-fit-")
        out = Path(temporary.name)
    common = dict(
        seed=int(seed),
        walkers=int(walkers),
        resume=bool(resume),
        overwrite=bool(overwrite),
        progress=bool(progress),
        stop_when_converged=bool(stop_when_converged),
    )
    try:
        if cp is None:
            from bayestouch.inference.raw import run_raw_fit

            run_raw_fit(
                data, out, steps=steps or 1500, budget_s=None if budget_s == "auto" else budget_s, **common, **options
            )
        else:
            from bayestouch.inference.run import DEFAULT_BUDGET_S, run_contact_fit

            opts = dict(options)
            normals = opts.pop("normals", None)
            if normals is None:
                normals = cp.normals
            elif normals is False:
                normals = None
            elif normals is True or isinstance(normals, str | bytes):
                raise BadInput(
                    f"fit: normals={normals!r}: expected an (n, 3) array of outward unit normals, one per contact, "
                    "False to ignore the data's normals, or None (the default) to use them"
                )
            free = opts.pop("free", cp.free)
            run_contact_fit(
                cp.points,
                out,
                steps=steps or 20000,
                budget_s=DEFAULT_BUDGET_S if budget_s == "auto" else budget_s,
                normals=normals,
                free=free,
                **common,
                **opts,
            )
    except BaseException:
        if temporary is not None:
            temporary.cleanup()
        raise
    return Fit(out, _temporary=temporary)


def simulate(
    obj="egg",
    *,
    strokes: int = 1,
    seed: int = 0,
    device_seed: int | None = None,
    duration: float = 2.0,
    rate: float = 50.0,
    depth=3e-4,
    mode: str | None = None,
    hold_currents=(0.15, 0.05, 0.05),
    force: float | None = None,
    models=MODELS,
    progress: bool = False,
    out=None,
    overwrite: bool = False,
):
    """Record random strokes of the virtual finger over an object.

    Parameters
    ----------
    obj : str, path or SceneObject
        An object's name (``"egg"``: from ``models/objects`` when that folder has it, else the shipped one), a TOML
        file, or an object.
    strokes : int
        Number of strokes (each ``duration`` s at 1 cm/s, ``rate`` frames/s), 1 to
        :data:`~bayestouch.scene.paths.MAX_PATHS`.
    seed : int
        Seeds the strokes and the noise; ``device_seed`` (default ``seed``) picks the simulated finger (its
        fixed-pattern gains).
    depth : float or sequence of float, metres
        Pressing depth, or one per stroke in turn (several depths let a calibration identify the response).
    mode : {"physics", "empirical"}, optional
        Taxel response (default ``models/taxels.toml``).
    hold_currents : (3,) float, amperes
        Hold currents of the three wires.
    force : float, newtons, optional
        Press to this normal force instead of a depth.
    out : path, optional
        Also write the recording there (netCDF; an existing file is refused unless ``overwrite``).

    Returns
    -------
    xarray.Dataset
        The recording (:mod:`bayestouch.io.recording`).
    """
    from bayestouch import __version__
    from bayestouch.io.recording import MAX_FRAMES, write_recording
    from bayestouch.physics.virtual import finger_name, load_finger, recording_dataset
    from bayestouch.scene.objects import SceneObject, load_object
    from bayestouch.scene.paths import MAX_PATHS
    from bayestouch.scene.strokes import random_strokes

    check_bool(progress, "progress")
    check_bool(overwrite, "overwrite")
    _check_seed(seed)
    if device_seed is not None:
        _check_seed(device_seed)
    for name, value in (("duration", duration), ("rate", rate)):
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            unit = "seconds" if name == "duration" else "frames/s"
            raise BadInput(f"{name}: expected a number ({unit}), got {value!r}")
    if not (0 < duration <= 600 and 1 <= rate <= 2000 and duration * rate >= 2):
        raise BadInput(
            f"duration, rate: expected 0 < duration ≤ 600 s, 1 ≤ rate ≤ 2000 frames/s and at least 2 frames a stroke, "
            f"got {duration!r} s at {rate!r} frames/s"
        )
    if isinstance(strokes, int | np.integer) and not isinstance(strokes, bool):
        if strokes * int(np.ceil(duration * rate)) > MAX_FRAMES:
            raise BadInput(
                f"strokes × duration × rate: {strokes} × {duration:g} s × {rate:g}/s is more than {MAX_FRAMES} frames "
                "in one recording; split it into several"
            )
    if not isinstance(models, str | os.PathLike):
        raise BadInput(f"models: expected the path of a parameter folder, got {type(models).__name__}")
    models = Path(models)
    if out is not None and Path(out).suffix != ".nc":
        raise BadInput(f"out: a recording is a netCDF file; expected a name ending in .nc, got {out!r}")
    if force is not None and (isinstance(force, bool) or not isinstance(force, int | float)):
        raise BadInput(f"force: expected a number of newtons in (0, 2], got {force!r}")
    if np.ndim(hold_currents) != 1:
        raise BadInput(f"hold_currents: expected the three wires' currents in amperes, got {hold_currents!r}")
    try:
        depths = [float(d) for d in np.atleast_1d(np.asarray(depth, dtype=float))]
    except (TypeError, ValueError):  # text, a ragged nesting
        depths = []
    if not depths or not all(0 < d <= 2e-3 for d in depths):
        raise BadInput(f"depth: each pressing depth must be in (0, 2e-3] metres, got {depth!r}")
    check_int(strokes, "strokes", 1, MAX_PATHS)
    if force is not None and not (0 < force <= 2.0):
        raise BadInput(f"force: expected newtons in (0, 2], got {force!r}")
    try:
        currents = [float(c) for c in hold_currents]
    except (TypeError, ValueError):
        raise BadInput(f"hold_currents: expected the three wires' currents in amperes, got {hold_currents!r}") from None
    if len(currents) != 3:
        raise BadInput(f"hold_currents: expected the three wires' currents in amperes, got {len(currents)} values")
    scene = obj if isinstance(obj, SceneObject) else load_object(obj, models)
    finger_seed = seed if device_seed is None else device_seed
    vf = load_finger(models, seed=finger_seed)
    max_current = float(vf.wire.max_current)
    if not all(0 <= c <= max_current for c in currents):
        raise BadInput(f"hold_currents: wire currents must each be in [0, {max_current:g}] A (amperes), got {currents}")
    if out is not None and Path(out).exists() and not overwrite:  # after every check of the arguments
        raise BadInput(f"out: {out} already exists; pass overwrite=True (--overwrite) to replace it")
    plan = random_strokes(scene, strokes, seed=seed, duration=duration, rate=rate, depth=depths[0])
    plan = [s._replace(depth=depths[i % len(depths)]) for i, s in enumerate(plan)]
    ds = recording_dataset(
        scene,
        plan,
        vf,
        seed,
        mode=mode,
        attrs={
            "object": scene.name,
            "object_file": str(obj) if isinstance(obj, str | os.PathLike) else scene.name,
            "seed": seed,
            **({} if device_seed is None else {"device_seed": finger_seed}),
            "finger": finger_name(finger_seed),
            "mode": mode or vf.mode,
            "wire_hold_currents_A": ",".join(f"{c:g}" for c in currents),
            "software": f"bayestouch {__version__}",
        },
        hold_currents=currents,
        force=force,
        progress=progress,
    )
    if out is not None:
        if overwrite:  # an earlier recording is kept, never deleted
            set_aside([out], "simulate")
        # without overwrite, a file that appeared since the check above (another run writing the same name) is
        # kept and this recording written beside it, with a BadInput naming both
        write_recording(ds, out, overwrite=overwrite)
    return ds


def calibrate(recording, obj, *, models=MODELS, out=None, overwrite: bool = False):
    """Estimate the finger's per-taxel log-gains, their standard errors, the common response factor and the read-out
    noise scale from strokes over a known object (:func:`bayestouch.inference.raw.calibrate.calibrate_device`).

    Parameters
    ----------
    recording : path or xarray.Dataset
        Strokes over ``obj`` (at least 2; several depths identify the response factor).
    obj : str, path or SceneObject
        The touched object in the recording's world frame: a shipped name, a TOML file or an object.
    out : path, optional
        Also write the device file (TOML) there, for ``fit(recording, calibration=...)``; an existing file is
        refused unless ``overwrite``.

    Returns
    -------
    DeviceCalibration
    """
    from bayestouch.inference.raw.calibrate import calibrate_device
    from bayestouch.io.device_file import device_file_text
    from bayestouch.scene.objects import SceneObject, load_object

    check_bool(overwrite, "overwrite")
    if out is not None:
        out = Path(out)
        if out.suffix != ".toml":
            raise BadInput(f"out: {out}: expected a .toml device file")
        if out.exists() and not overwrite:
            raise BadInput(f"out: {out} exists; pass overwrite=True (--overwrite) to replace it")
    scene = obj if isinstance(obj, SceneObject) else load_object(obj, models)
    cal = calibrate_device(recording, scene, models=models, object_name=str(obj) if isinstance(obj, str) else None)
    if out is not None:
        text = device_file_text(cal)  # refused (BadInput) before an earlier file is moved
        if overwrite:  # an earlier device file is kept, never deleted
            set_aside([out], "calibrate")
        # without overwrite, a file that appeared since the check above (another run writing the same name) is
        # kept and this one written beside it, with a BadInput naming both
        with atomic_path(out, replace=overwrite) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
    return cal
