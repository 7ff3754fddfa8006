"""visco: identify viscoelastic properties of cells with an AFM, from Python.

The same Rust code as the ``visco`` command (not a second implementation):

- :func:`read` / :func:`read_all`: a recording CSV or a vendor file (JPK .jpk-force,
  .jpk-force-map, .jpk-qi-data; AFM Workshop .csv and zipped maps; NT-MDT .txt; Asylum
  Research .ibw; Optics11 Chiaro .txt; afmformats .tab) -> :class:`Recording`.
- :meth:`Recording.from_arrays`: data that came from elsewhere (e.g. afmformats).
- :func:`identify`: the viscoelastic parameters and the fit (``visco identify``'s report).
- :func:`diagnose`: the physics the nominal model left out, named and modelled
  (``visco diagnose``'s report), with the per-sample series as numpy arrays.
- :func:`simulate`: one DIVE tap or force curve on the simulated instrument, with effects
  switched on by name.

Units are SI throughout and in every name: ``_m`` metres, ``_s`` seconds, ``_hz`` hertz,
``_n`` newtons, ``_n_per_m`` N/m, ``_ns_per_m`` N*s/m, ``_n_per_m3`` N/m^3, ``_kg`` kilograms.
Sign convention (shared/spec/recording.md): z up; the deflection D is negative when the
sample pushes the tip up.

Refusals raise :class:`ViscoError` (a ``ValueError``) whose text is the command line's
``FILE[:ENTRY][:LINE]: reason (fix: ...)``.
"""

from __future__ import annotations

import json as _json
import os as _os
import tempfile as _tempfile
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, Union

import numpy as _np

from . import _native
from ._native import ViscoError

__version__: str = _native.__version__

__all__ = [
    "Recording",
    "Report",
    "Simulation",
    "ViscoError",
    "read",
    "read_all",
    "identify",
    "diagnose",
    "simulate",
    "EFFECTS",
    "SETUPS",
    "COLUMN_UNITS",
]

PathLike = Union[str, "_os.PathLike[str]"]

#: Units of the standard columns.
COLUMN_UNITS: Dict[str, str] = {
    "t_s": "s",
    "u_m": "m",
    "d_m": "m",
    "x_m": "m",
    "y_m": "m",
    "tap": "1 (tap index)",
}

#: Effect identifiers -> the physics each stands for (``recording.md``'s vocabulary).
EFFECTS: Dict[str, str] = dict(_native.effects())

#: Simulated setups for :func:`simulate`: name -> (is a tap, k N/m, tip radius m, rate Hz).
SETUPS: Dict[str, tuple] = {s[0]: tuple(s[1:]) for s in _native.setups()}

_STANDARD = ("t_s", "u_m", "d_m", "x_m", "y_m", "tap")


def _tempdir(rows: int = 0, cols: int = 3) -> "_tempfile.TemporaryDirectory[str]":
    """A temporary directory for the files the host API reads or writes on the way: in RAM
    (/dev/shm) when it has room for them, since the writer syncs every file to disk, which
    on a temporary file is time spent for nothing (a 4000-row curve: ~20 ms of ~40)."""
    shm = "/dev/shm"
    try:
        st = _os.statvfs(shm)
        room = st.f_bavail * st.f_frsize
        # ~25 bytes per cell, and the outputs (series, figures) beside it.
        if _os.access(shm, _os.W_OK) and rows * cols * 25 * 4 + (64 << 20) < room // 2:
            return _tempfile.TemporaryDirectory(prefix="visco-", dir=shm)
    except OSError:
        pass
    return _tempfile.TemporaryDirectory(prefix="visco-")


def _unit_of(name: str) -> str:
    if name in COLUMN_UNITS:
        return COLUMN_UNITS[name]
    for suffix, unit in (
        ("_n_per_m3", "N/m^3"),
        ("_ns_per_m3", "N*s/m^3"),
        ("_ns_per_m", "N*s/m"),
        ("_n_per_m", "N/m"),
        ("_m", "m"),
        ("_s", "s"),
        ("_hz", "Hz"),
        ("_n", "N"),
        ("_v", "V"),
    ):
        if name.endswith(suffix):
            return unit
    return "as named (no unit suffix)"


class Recording:
    """A recording (shared/spec/recording.md): metadata and named columns.

    Attributes:
        metadata: dict keyed by the contract's names: ``visco-recording`` (format version),
            ``mode`` (``"dive"``, ``"sve"`` or ``"force-curve"``), ``sample_rate_hz`` (Hz),
            ``cantilever_k_n_per_m`` (N/m), optional ``cantilever_c_ns_per_m`` (N*s/m),
            ``cantilever_m_kg`` (kg), ``cantilever_f0_hz`` (Hz), ``cantilever_q`` (1),
            ``tip_radius_m`` (m), optional ``deflection_noise_m`` (m); every other key as
            text (vendor values, ``segments``, ...).
        columns: dict name -> 1-D numpy array, in file order: ``t_s`` (s), ``u_m`` (m),
            ``d_m`` (m), optional ``x_m``, ``y_m`` (m), ``tap`` (int64) and the extra columns
            (e.g. ``segment``, ``force_vendor_n`` in N, ``height_piezo_m`` in m).
        source: where it came from (a path, or a description); errors name it.
        curve: the curve's index in a map (0 for a single curve).
    """

    __slots__ = ("metadata", "columns", "source", "curve")

    def __init__(
        self,
        metadata: Mapping[str, Any],
        columns: Mapping[str, Any],
        source: str = "<recording>",
        curve: int = 0,
    ) -> None:
        self.metadata: Dict[str, Any] = dict(metadata)
        self.columns: Dict[str, _np.ndarray] = {}
        for name, values in columns.items():
            if name == "tap":
                self.columns[name] = _np.asarray(values, dtype=_np.int64)
            else:
                self.columns[name] = _np.ascontiguousarray(values, dtype=_np.float64)
        self.source: str = source
        self.curve: int = curve

    # -- the standard columns ------------------------------------------------------------
    @property
    def t(self) -> _np.ndarray:
        """Time ``t_s``, s, strictly increasing."""
        return self.columns["t_s"]

    @property
    def u(self) -> _np.ndarray:
        """Commanded base position U, ``u_m``, m (z up)."""
        return self.columns["u_m"]

    @property
    def d(self) -> _np.ndarray:
        """Measured deflection D, ``d_m``, m (negative when the sample pushes the tip up)."""
        return self.columns["d_m"]

    @property
    def x(self) -> Optional[_np.ndarray]:
        """Lateral tip position X, ``x_m``, m, or None."""
        return self.columns.get("x_m")

    @property
    def y(self) -> Optional[_np.ndarray]:
        """Lateral tip position Y, ``y_m``, m, or None."""
        return self.columns.get("y_m")

    @property
    def tap(self) -> Optional[_np.ndarray]:
        """Tap index (int64), or None."""
        return self.columns.get("tap")

    @property
    def extras(self) -> Dict[str, _np.ndarray]:
        """The extra columns (everything but t_s, u_m, d_m, x_m, y_m, tap), by name."""
        return {k: v for k, v in self.columns.items() if k not in _STANDARD}

    @property
    def mode(self) -> str:
        """``"dive"``, ``"sve"`` or ``"force-curve"``."""
        return str(self.metadata["mode"])

    def units(self) -> Dict[str, str]:
        """Each column's unit, read from its name's suffix (``_m`` metres, ``_s`` seconds,
        ``_n`` newtons, ...)."""
        return {name: _unit_of(name) for name in self.columns}

    def __len__(self) -> int:
        return len(self.columns["t_s"])

    def __repr__(self) -> str:
        return (
            f"<visco.Recording {self.mode} from {self.source!r}: {len(self)} samples, "
            f"columns {list(self.columns)}>"
        )

    # -- construction and writing --------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        t: Any,
        u: Any,
        d: Any,
        *,
        mode: str = "force-curve",
        spring_constant: float,
        tip_radius: float,
        sample_rate: Optional[float] = None,
        damping: Optional[float] = None,
        mass: Optional[float] = None,
        resonance: Optional[float] = None,
        quality_factor: Optional[float] = None,
        deflection_noise: Optional[float] = None,
        x: Any = None,
        y: Any = None,
        tap: Any = None,
        extra: Optional[Mapping[str, Any]] = None,
        metadata: Optional[Mapping[str, Any]] = None,
        source: str = "<from_arrays>",
    ) -> "Recording":
        """A recording from arrays that came from elsewhere, checked against the contract
        (the same checks and messages as the command's reader; the message names ``source``
        and the CSV line the offending row would have).

        Args:
            t: time, s, strictly increasing.
            u: commanded base position U, m, z up (the piezo's height).
            d: deflection D, m; negative when the sample pushes the tip up (the opposite of
                the vendors' force sign: D = -F/k).
            mode: ``"force-curve"`` (default), ``"dive"`` or ``"sve"``.
            spring_constant: cantilever K, N/m.
            tip_radius: spherical tip radius R, m.
            sample_rate: nominal sampling rate, Hz (default: 1 / median time step).
            damping: cantilever C, N*s/m.  mass: effective mass M, kg.
            resonance: first-mode f0, Hz.  quality_factor: first-mode Q.
            deflection_noise: RMS noise of D, m.
            x, y: lateral tip position, m (together).  tap: tap index per sample.
            extra: more columns by name (use unit suffixes: ``force_n``, ``height_m``).
            metadata: more ``key: value`` lines, kept as text.
            source: how errors name this recording.

        Raises:
            ViscoError: the arrays break the contract (file = ``source``, line = the CSV line).
        """
        t = _np.ascontiguousarray(t, dtype=_np.float64)
        if sample_rate is None:
            dt = _np.diff(t)
            if len(dt) == 0 or not _np.median(dt) > 0:
                raise ValueError("sample_rate cannot be inferred from t; pass sample_rate=HZ")
            sample_rate = float(1.0 / _np.median(dt))
        meta: Dict[str, Any] = {
            "visco-recording": 1,
            "mode": mode,
            "sample_rate_hz": float(sample_rate),
            "cantilever_k_n_per_m": float(spring_constant),
        }
        for key, value in (
            ("cantilever_c_ns_per_m", damping),
            ("cantilever_m_kg", mass),
            ("cantilever_f0_hz", resonance),
            ("cantilever_q", quality_factor),
        ):
            if value is not None:
                meta[key] = float(value)
        meta["tip_radius_m"] = float(tip_radius)
        if deflection_noise is not None:
            meta["deflection_noise_m"] = float(deflection_noise)
        for key, value in (metadata or {}).items():
            meta[key] = str(value)
        cols: Dict[str, Any] = {"t_s": t, "u_m": u, "d_m": d}
        if (x is None) != (y is None):
            raise ValueError("x and y go together")
        if x is not None:
            cols["x_m"], cols["y_m"] = x, y
        if tap is not None:
            cols["tap"] = tap
        for key, value in (extra or {}).items():
            cols[key] = value
        rec = cls(meta, cols, source=source)
        rec.check()
        return rec

    def _native_columns(self) -> List[tuple]:
        n = len(self)
        out = []
        for name, values in self.columns.items():
            arr = _np.ascontiguousarray(values, dtype=_np.float64)
            if arr.ndim != 1 or len(arr) != n:
                raise ValueError(
                    f"{self.source}: column `{name}` has shape {arr.shape}, "
                    f"not ({n},) like t_s"
                )
            out.append((name, arr))
        return out

    def write(self, path: PathLike) -> None:
        """Writes the recording CSV (atomically; checked against the contract)."""
        _native.write(self.metadata, self._native_columns(), _os.fspath(path))

    def check(self) -> None:
        """Checks the recording against the contract (``ViscoError`` naming ``source``)."""
        with _tempdir(len(self), len(self.columns)) as tmp:
            _native.write(
                self.metadata,
                self._native_columns(),
                _os.path.join(tmp, "check.csv"),
                self.source,
            )


class Report(dict):
    """A report: the JSON the command writes, as a dict (``report["rms_misfit_m"]``, ...),
    plus the per-sample series as numpy arrays in ``report.series`` (name -> array; unit from
    the name's suffix; ``phase`` is a list of str). ``to_dict()`` gives the plain JSON
    dict."""

    series: Dict[str, Any]

    def __init__(self, data: Mapping[str, Any], series: Mapping[str, Any]):
        super().__init__(data)
        self.series = dict(series)

    def to_dict(self) -> Dict[str, Any]:
        """The report as plain JSON-compatible dicts and lists."""
        return _json.loads(_json.dumps(dict(self)))


def _overrides(
    spring_constant: Optional[float],
    sensitivity: Optional[float],
    tip_radius: Optional[float],
    sample_rate: Optional[float],
) -> Dict[str, Optional[float]]:
    return dict(
        spring_constant=spring_constant,
        sensitivity=sensitivity,
        tip_radius=tip_radius,
        sample_rate=sample_rate,
    )


def read(
    path: PathLike,
    *,
    curve: Optional[int] = None,
    spring_constant: Optional[float] = None,
    sensitivity: Optional[float] = None,
    tip_radius: Optional[float] = None,
    sample_rate: Optional[float] = None,
) -> Recording:
    """Reads a recording CSV, or imports a vendor file as ``visco import`` does.

    Vendor formats: JPK .jpk-force, .jpk-force-map, .jpk-qi-data; AFM Workshop .csv (and
    its maps, zipped); NT-MDT .txt; Asylum Research .ibw; Optics11 Chiaro .txt; afmformats
    .tab. The result is a ``force-curve`` recording: ``u_m`` the base position (m,
    z up), ``d_m`` the deflection (m), ``t_s`` from the vendor's rates (s), plus ``segment``
    and, where the file has one, ``force_vendor_n`` (N, vendor sign: positive = repulsive).

    Args:
        path: the file.
        curve: for a map, which curve (its ``index/N`` number); required for maps (or use
            :func:`read_all`).
        spring_constant: cantilever K, N/m (overrides the file's).
        sensitivity: deflection sensitivity, m per unit of the raw signal (m/V for JPK and
            AFM Workshop, m/nA for NT-MDT); overrides the file's.
        tip_radius: spherical tip radius, m (required for vendor files: none stores it).
        sample_rate: Hz, for files without a time base (AFM Workshop, NT-MDT).

    Raises:
        ViscoError: the file is refused; ``str(e)`` is the command's
            ``FILE[:ENTRY][:LINE]: reason (fix: ...)``.
    """
    _, recs, warnings = _native.read(
        _os.fspath(path),
        curve,
        False,
        **_overrides(spring_constant, sensitivity, tip_radius, sample_rate),
    )
    _warn(warnings)
    c, meta, cols = recs[0]
    return Recording(meta, dict(cols), source=_os.fspath(path), curve=c)


def read_all(
    path: PathLike,
    *,
    spring_constant: Optional[float] = None,
    sensitivity: Optional[float] = None,
    tip_radius: Optional[float] = None,
    sample_rate: Optional[float] = None,
) -> Dict[int, Recording]:
    """Every curve of a file (a map's curves by their ``index/N`` number; a single curve
    as ``{0: rec}``). Arguments as :func:`read`."""
    _, recs, warnings = _native.read(
        _os.fspath(path),
        None,
        True,
        **_overrides(spring_constant, sensitivity, tip_radius, sample_rate),
    )
    _warn(warnings)
    return {
        c: Recording(meta, dict(cols), source=_os.fspath(path), curve=c)
        for c, meta, cols in recs
    }


def _warn(warnings: Iterable[str]) -> None:
    import warnings as _w

    for text in warnings:
        _w.warn(text, stacklevel=3)


def _series(cols: Iterable[tuple]) -> Dict[str, Any]:
    return {name: values for name, values in cols}


def identify(
    rec: Union[Recording, PathLike],
    *,
    regressor: str = "offset",
    element_pitch: float = 100e-9,
    lattice_origin: Optional[Sequence[float]] = None,
    readout: float = 10e-3,
    pixels: int = 50,
    lines: Optional[int] = None,
    contact_sigma: float = 5.0,
    out_dir: Optional[PathLike] = None,
) -> Report:
    """Identifies a recording's viscoelastic parameters and its fit: ``visco identify``.

    ``rec`` is a :class:`Recording` or the path of a recording CSV. The result is the report
    the command writes (same keys, same numbers): for a force curve the contact point,
    ``k_a_n_per_m3`` (N/m^3) and ``c_a_ns_per_m3`` (N*s/m^3) of the element bed, aggregate
    ``k_n_per_m``/``c_ns_per_m`` and per element, ``rms_misfit_m`` (m); for DIVE per tap;
    for SVE the maps' summary. ``report.series`` holds the fit per sample (``t_s``,
    ``u_m``, ``d_recorded_m``, ``d_simulated_m``, ``residual_m``, ...).

    Args:
        regressor: DIVE regressor, ``"offset"`` (default) or ``"paper"``.
        element_pitch: lateral pitch of the element bed, m.
        lattice_origin: (x, y) of element (0, 0), m, for exact element counts.
        readout: DIVE read-out window at the end of each dwell, s.
        pixels, lines: SVE map size.
        contact_sigma: force curves: contact threshold in standard deviations of the free
            deflection.
        out_dir: keep the command's output files (report JSON, series CSV, figures, SVE maps)
            in this directory; by default they go to a temporary one and are removed.

    Raises:
        ViscoError: as the command refuses (file, line, reason).
    """
    rows, cols = (len(rec), len(rec.columns)) if isinstance(rec, Recording) else (0, 3)
    with _tempdir(rows, cols) as tmp:
        directory = _os.fspath(out_dir) if out_dir is not None else tmp
        if isinstance(rec, Recording):
            stem = _stem(rec.source)
            path = _os.path.join(tmp, f"{stem}.csv")
            _native.write(rec.metadata, rec._native_columns(), path, rec.source)
            label: Optional[str] = rec.source
        else:
            path = _os.fspath(rec)
            stem = _stem(path)
            label = None
        json_path = _os.path.join(directory, f"{stem}.json")
        try:
            text, files = _native.identify_file(
                path,
                json_path,
                directory,
                regressor,
                element_pitch,
                None if lattice_origin is None else tuple(lattice_origin),
                readout,
                pixels,
                lines,
                contact_sigma,
            )
        except ViscoError as e:
            if label is not None and e.file == path:
                raise _renamed(e, path, label) from None
            raise
        data = _json.loads(text)
        fit = data.get("fit", {}) if isinstance(data.get("fit"), dict) else {}
        series_path = fit.get("series_csv") or _os.path.join(directory, f"{stem}_fit.csv")
        series = _series(_native.read_series(series_path)) if _os.path.exists(series_path) else {}
        if label is not None:
            data["recording"] = label
        return Report(data, series)


def _stem(source: str) -> str:
    base = _os.path.basename(source) or "recording"
    stem = base.split(".")[0] if not base.startswith(".") else base
    cleaned = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in stem)
    return cleaned or "recording"


def _renamed(e: ViscoError, path: str, label: str) -> ViscoError:
    """The same error, naming the recording's source instead of the temporary copy (line
    numbers are those of the recording as a CSV)."""
    text = str(e).replace(path, label, 1)
    new = ViscoError(text)
    for attr in ("entry", "line", "reason", "fix"):
        setattr(new, attr, getattr(e, attr, None))
    new.file = label
    return new


def diagnose(
    rec: Union[Recording, PathLike],
    *,
    alpha: float = 0.01,
    effects: Optional[Iterable[str]] = None,
    max_effects: int = 3,
    progress: Optional[Callable[[str], None]] = None,
) -> Report:
    """Finds the physics the nominal model left out of a recording: ``visco diagnose``.

    The nominal model (the cantilever's first mode and a spherical tip on a Kelvin-Voigt
    element bed) is fitted to half the samples and judged on the other half; each effect of
    the vocabulary (:data:`EFFECTS`) is tried as an extension and the ones the held-out data
    support are named, most important first.

    Returns the report the command writes (same keys and numbers, without the output file
    names): ``rms_before_m``/``rms_after_m`` (held-out RMS misfit, m), ``left_out`` (each
    effect with its explanation, where it acts, parameters in SI and evidence), ``nominal``,
    ``selection``, ``locate``. ``report.series`` holds every sample: ``t_s`` (s), ``u_m``,
    ``d_recorded_m``, ``d_nominal_m``, ``d_extended_m``, ``residual_before_m``,
    ``residual_after_m`` (m), ``phase`` (list of str), ``held_out`` (1 = held out).

    Runs with the GIL released; Ctrl-C (KeyboardInterrupt) stops it at the next step.

    Args:
        rec: a :class:`Recording` or the path of a recording CSV (vendor files: :func:`read`
            first).
        alpha: family-wise false-alarm rate of each selection step, in (0, 1).
        effects: only try these effect identifiers (default: all of :data:`EFFECTS`).
        max_effects: name at most this many.
        progress: called with a line of text at each step (the command's ``--quiet`` off).

    Raises:
        ViscoError: the recording is refused (file, line, reason).
        KeyboardInterrupt: interrupted.
    """
    if not isinstance(rec, Recording):
        rec = read(rec)
    # The contract, checked by the writer the command's reader mirrors (same refusals).
    rec.check()
    text, series = _native.diagnose(
        rec.metadata,
        rec._native_columns(),
        rec.source,
        alpha,
        max_effects,
        None if effects is None else list(effects),
        progress,
    )
    return Report(_json.loads(text), _series(series))


class Simulation:
    """A simulated tap or force curve (:func:`simulate`).

    Attributes:
        recording: the :class:`Recording` (with the plant's thermal noise and 16-bit ADC
            unless ``noise=False``).
        truth_d_m: the noise-free D with the effects, m.
        clean_d_m: the noise-free D without them, m (``truth_d_m - clean_d_m`` is what the
            effects do).
        noise_m: RMS of the noise on D, m.
        effects: per effect: ``{"effect": name, "parameters": {name: SI value},
            "peak_over_noise": largest |delta D| it alone causes / noise_m}``.
        setup: the setup's name.
    """

    __slots__ = ("recording", "truth_d_m", "clean_d_m", "noise_m", "effects", "setup")

    def __init__(self, recording, truth, clean, noise_m, effects, setup):
        self.recording: Recording = recording
        self.truth_d_m: _np.ndarray = truth
        self.clean_d_m: _np.ndarray = clean
        self.noise_m: float = noise_m
        self.effects: List[Dict[str, Any]] = effects
        self.setup: str = setup

    def __repr__(self) -> str:
        names = [e["effect"] for e in self.effects] or ["no effect"]
        return f"<visco.Simulation {self.setup}: {', '.join(names)}, {len(self.recording)} samples>"


def simulate(
    setup: str = "curve-colloid",
    effects: Iterable[str] = (),
    *,
    magnitude: float = 5.0,
    seed: int = 0,
    noise: bool = True,
) -> Simulation:
    """One DIVE tap or force curve on the simulated instrument, with effects by name.

    Args:
        setup: one of :data:`SETUPS`: taps (``dive``, the plant at the recording rate, two
            tones in the dwell) ``"tap-air"``, ``"tap-liquid"``, ``"tap-stiff"``; force curves
            (approach, hold, retract) ``"curve-colloid"``, ``"curve-soft"``, ``"curve-gel"``.
        effects: identifiers from :data:`EFFECTS` (``"adhesion"``, ``"stress-relaxation"``,
            ...); none gives the nominal physics only.
        magnitude: each effect's amplitude is calibrated so that alone it changes D by at most
            this many times the noise RMS (the concealed suite draws 3-10).
        seed: the draw of the effects' shapes, the tip's place on the bed and the noise.
        noise: add the thermal noise and the ADC (default) or not.

    The bed is the plant's lattice of discrete elements, not the continuum the diagnosis
    models; the truth (``truth_d_m``) is the simulator's and is labelled as such.
    """
    meta, cols, truth, clean, noise_m, found = _native.simulate(
        setup, list(effects), magnitude, seed, noise
    )
    rec = Recording(meta, dict(cols), source=f"<simulated {setup}, seed {seed}>")
    info = [
        {"effect": name, "parameters": dict(params), "peak_over_noise": ratio}
        for name, params, ratio in found
    ]
    return Simulation(rec, truth, clean, noise_m, info, setup)
