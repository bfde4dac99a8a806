"""Rig logs: read, validate, window and save a CSV log with its JSON sidecar.

A log is two files with the same stem (see the project README, "Log format"):

* ``STEM.csv``, one row per controller sample, header
  ``t_s,q2_ref_rad,q3_ref_rad,e2_pulses,e3_pulses,i2_A,i3_A``;
* ``STEM.json``, the sidecar with the rig constants, the reference trajectory,
  the start state and the search ranges of f1..f9.

:func:`load_log` checks everything and raises :class:`plant.LogError` (a
``ValueError``) with a one-line message naming the file and the line, column
or key at fault.
"""
from __future__ import annotations

import copy
import csv
import dataclasses
import io
import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from plant._errors import LogError
from plant.logs.fileio import write_text_atomic
from plant.logs.rig import Rig
from plant.logs.sidecar import (
    sidecar_error,
    parse_window,
    SidecarKeys,
    read_sidecar,
    read_text,
    rig_into_sidecar,
    short_text,
    rig_from_sidecar,
)
from plant.logs.trajectory import Trajectory

__all__ = [
    "COLUMNS",
    "ExperimentLog",
    "load_log",
    "as_log",
    "rig_from_sidecar",
    "example_log_path",
    "load_example",
]

#: Exact CSV header (the order of the columns in a file may differ).
COLUMNS = ("t_s", "q2_ref_rad", "q3_ref_rad", "e2_pulses", "e3_pulses", "i2_A", "i3_A")

#: Tolerance (s) of the check t_k == k * Ts and of window boundaries.
T_TOL_S = 1e-9

#: Largest allowed |q_ref_csv - trajectory(t)| (rad).
Q_REF_TOL_RAD = 1e-6

_EXAMPLE_STEM = "puma560_paper_rigid"


# --------------------------------------------------------------------------- helpers
def _resolve(path: str | os.PathLike) -> tuple[Path, Path, str]:
    """Return (csv path, json path, stem) for STEM, STEM.csv or STEM.json."""
    p = Path(path)
    if p.is_dir():
        raise sidecar_error(p, "log file is a directory (give STEM.csv with its STEM.json beside it)")
    name = p.name
    stem = name
    for suffix in (".csv", ".json"):
        if name.lower().endswith(suffix):
            stem = name[: -len(suffix)]
            break
    else:
        if p.suffix and p.exists():
            raise sidecar_error(p, f"a log is STEM.csv with its STEM.json sidecar, not a {p.suffix} file")
    if not stem:
        raise sidecar_error(p, "no file stem")
    return p.with_name(stem + ".csv"), p.with_name(stem + ".json"), stem


# ----------------------------------------------------------------------- CSV parsing
def _split_rows(text: str, path: Path):
    """Split CSV text into (header cells, body rows as cell lists or None, body line numbers,
    body line strings or None).

    Files without a quote character (every file this library writes) take a
    fast path: plain line and comma splitting, with the numbers parsed later by
    numpy's C reader. Files with quotes go through the :mod:`csv` module.
    """
    if '"' not in text:
        raw = text.split("\n")
        if "\r" in text:
            raw = [ln[:-1] if ln.endswith("\r") else ln for ln in raw]
        header = raw[0].split(",")
        body = raw[1:]
        while body and not body[-1].strip():  # trailing blank lines are allowed
            body.pop()
        lines = np.arange(2, len(body) + 2, dtype=np.int64)
        return header, None, lines, body
    reader = csv.reader(io.StringIO(text))
    rows: list = []
    line_nums: list = []
    try:
        header = next(reader)
        for row in reader:
            rows.append(row)
            line_nums.append(reader.line_num)
    except csv.Error as e:
        raise sidecar_error(path, f"line {reader.line_num}: malformed CSV ({e})") from None
    while rows and (not rows[-1] or all(not c.strip() for c in rows[-1])):
        rows.pop()
        line_nums.pop()
    return header, rows, np.asarray(line_nums, dtype=np.int64), None


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    """Parse and check the CSV; returns column name -> array (pulses int64)."""
    text = read_text(path, "log file")
    if not text.strip():
        raise sidecar_error(path, "empty file (no header row)")
    header, rows, lines, body = _split_rows(text, path)
    if not header or all(not h.strip() for h in header):
        raise sidecar_error(path, "line 1: empty header row")
    names = [h.strip() for h in header]
    seen = set()
    for h in names:
        if h in seen:
            raise sidecar_error(path, f"line 1: duplicate column '{h}'")
        seen.add(h)
    missing = [c for c in COLUMNS if c not in seen]
    extra = [h for h in names if h not in COLUMNS]
    if missing or extra:
        parts = []
        if missing:
            parts.append("missing column(s) " + ", ".join(f"'{c}'" for c in missing))
        if extra:
            parts.append("unexpected column(s) " + ", ".join(f"'{c}'" for c in extra))
        raise sidecar_error(path, "line 1: " + "; ".join(parts)
                   + " (expected header " + ",".join(COLUMNS) + ")")
    n = len(body) if rows is None else len(rows)
    if n == 0:
        raise sidecar_error(path, "no data rows (header only)")
    ncol = len(names)

    # ragged rows
    if rows is None:
        counts = [ln.count(",") + 1 if ln.strip() else 0 for ln in body]
    else:
        counts = [len(r) for r in rows]
    lengths = np.fromiter(counts, dtype=np.int64, count=n)
    bad = np.flatnonzero(lengths != ncol)
    if bad.size:
        i = int(bad[0])
        if lengths[i] == 0:
            raise sidecar_error(path, f"line {lines[i]}: empty row, expected {ncol} fields")
        raise sidecar_error(path, f"line {lines[i]}: ragged row with {lengths[i]} fields, expected {ncol}")

    def cell(i: int, ci: int) -> str:
        return body[i].split(",")[ci] if rows is None else rows[i][ci]

    def parses(text: str) -> bool:
        # the same parser as the bulk conversion below
        if not text.strip():
            return False
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if rows is None:
                    np.loadtxt([text], delimiter=",", comments=None, dtype=float, ndmin=2)
                else:
                    np.array([text], dtype=float)
        except ValueError:
            return False
        return True

    def locate_non_numeric() -> LogError:
        for i in range(n):
            if rows is None and parses(body[i]):
                continue
            for ci, name in enumerate(names):
                c = cell(i, ci)
                if not parses(c):
                    return sidecar_error(path, f"line {lines[i]}, column '{name}': "
                                      f"non-numeric value {short_text(c)}")
        return sidecar_error(path, "non-numeric values")  # pragma: no cover - parsers disagree

    try:
        if rows is None:
            data = np.loadtxt(body, delimiter=",", comments=None, dtype=float, ndmin=2)
        else:
            data = np.array(rows, dtype=float)
    except ValueError:
        raise locate_non_numeric() from None
    if data.shape != (n, ncol):  # pragma: no cover - guarded by the ragged check
        raise locate_non_numeric()

    out: dict[str, np.ndarray] = {}
    finite = np.isfinite(data)
    if not finite.all():
        i, ci = (int(x) for x in np.argwhere(~finite)[0])
        raise sidecar_error(path, f"line {lines[i]}, column '{names[ci]}': "
                         f"non-finite value {short_text(cell(i, ci).strip())}")
    for ci, name in enumerate(names):
        a = np.ascontiguousarray(data[:, ci])
        if name.endswith("_pulses"):
            nonint = (a != np.round(a)) | (np.abs(a) > 2.0**53)
            if nonint.any():
                i = int(np.flatnonzero(nonint)[0])
                raise sidecar_error(path, f"line {lines[i]}, column '{name}': "
                                 f"non-integer pulse value {short_text(cell(i, ci).strip())}")
            a = a.astype(np.int64)
        out[name] = a
    out["_lines"] = lines
    return out


# ---------------------------------------------------------------------- the log type
def _frozen_array(a, dtype) -> np.ndarray:
    a = np.array(a, dtype=dtype)  # private copy
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ExperimentLog:
    """One P-control experiment: the logged samples, the rig and the reference.

    Build it with :func:`load_log`. The arrays are read-only. The log may be
    a window of a longer run that started at t = 0 from
    ``rig.q0_rad`` / ``rig.qd0_rad_per_s``; then ``t[0] = start_index * Ts``
    and a simulation must start at t = 0 and run ``n_total`` samples.

    Two logs compare equal when they hold the same data (``t``, ``q_ref``,
    ``e_pulses``, ``i_A``, ``rig``, ``trajectory``, ``start_index``,
    ``window_s`` and ``sidecar``), wherever they are stored: ``path`` and
    ``name`` are not compared.

    Attributes
    ----------
    path : Path
        The CSV file (``STEM.csv``).
    name : str
        The stem.
    t : ndarray, shape (n,), float
        Sample times t_k = k Ts (s), k = start_index .. start_index + n - 1.
    q_ref : ndarray, shape (n, 2), float
        Reference angles of joints 2 and 3 at t_k (rad).
    e_pulses : ndarray, shape (n, 2), int64
        Tracking errors ref_pulses - act_pulses at t_k (motor-encoder pulses).
    i_A : ndarray, shape (n, 2), float
        Motor currents applied over [t_k, t_k + Ts) (A).
    rig : Rig
        Rig constants from the sidecar.
    trajectory : Trajectory
        Reference trajectory (time measured from the start of the run).
    start_index : int
        k0, the sample index of the first row (0 for a full run).
    window_s : tuple of 2 float or None
        (t_start, t_stop) (s) if the log is the window [t_start, t_stop) of a
        longer run, else None.
    sidecar : dict
        The raw sidecar, for reference (treat as read-only).
    """

    path: Path
    name: str
    t: np.ndarray
    q_ref: np.ndarray
    e_pulses: np.ndarray
    i_A: np.ndarray
    rig: Rig
    trajectory: Trajectory
    start_index: int = 0
    window_s: tuple | None = None
    sidecar: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _frozen_array(self.t, float).reshape(-1)
        n = t.shape[0]
        arrays = {
            "q_ref": _frozen_array(self.q_ref, float),
            "e_pulses": _frozen_array(self.e_pulses, np.int64),
            "i_A": _frozen_array(self.i_A, float),
        }
        for name, a in arrays.items():
            if a.shape != (n, 2):
                raise ValueError(f"ExperimentLog: {name} must have shape ({n}, 2), got {a.shape}")
        object.__setattr__(self, "path", Path(self.path))
        object.__setattr__(self, "t", t)
        for name, a in arrays.items():
            object.__setattr__(self, name, a)
        object.__setattr__(self, "start_index", int(self.start_index))
        if self.window_s is not None:
            object.__setattr__(self, "window_s", (float(self.window_s[0]), float(self.window_s[1])))

    # ---------------------------------------------------------------- properties
    @property
    def n_samples(self) -> int:
        """Number of rows n."""
        return int(self.t.shape[0])

    @property
    def sample_index(self) -> np.ndarray:
        """Sample indices k of the rows, ``start_index + arange(n)``, shape (n,), int64."""
        return self.start_index + np.arange(self.n_samples, dtype=np.int64)

    @property
    def n_total(self) -> int:
        """Samples a simulation must run from t = 0 to cover the log: ``start_index + n``."""
        return self.start_index + self.n_samples

    # ------------------------------------------------------------------- methods
    def replace(self, **changes: Any) -> "ExperimentLog":
        """Return a copy with some fields replaced (:func:`dataclasses.replace`).

        Unless ``sidecar`` is among the changes, the copy's sidecar is updated
        with its rig, trajectory, ``n_samples`` and ``window_s`` (what
        :meth:`save` writes), so a saved and reloaded copy compares equal.

        Parameters
        ----------
        **changes
            New values of fields (e.g. ``e_pulses=...``, ``i_A=...``).

        Returns
        -------
        ExperimentLog
        """
        new = dataclasses.replace(self, **changes)
        if "sidecar" not in changes:
            new = dataclasses.replace(new, sidecar=new._synced_sidecar())
        return new

    def window(self, t_start: float, t_stop: float) -> "ExperimentLog":
        """Cut the rows with ``t_start <= t < t_stop`` (s, times from the start of the run).

        Boundaries are compared with a tolerance of 1e-9 s, so a boundary on a
        sample time counts as exactly on it.

        Parameters
        ----------
        t_start, t_stop : float
            Window boundaries (s), finite, ``t_start < t_stop``.

        Returns
        -------
        ExperimentLog
            The window, with ``start_index`` = k of its first row, ``window_s``
            = (t_start, t_stop) (intersected with this log's window, if any;
            t_start clipped at 0) and the sidecar updated (``n_samples``,
            ``window_s``).

        Raises
        ------
        ValueError
            Non-finite or inverted boundaries, or no row in the window.
        """
        t_start, t_stop = float(t_start), float(t_stop)
        if not (math.isfinite(t_start) and math.isfinite(t_stop)) or not t_start < t_stop:
            raise ValueError(f"window: need finite t_start < t_stop, got [{t_start}, {t_stop})")
        t_start = max(t_start, 0.0)
        if self.window_s is not None:
            t_start = max(t_start, self.window_s[0])
            t_stop = min(t_stop, self.window_s[1])
        mask = (self.t >= t_start - T_TOL_S) & (self.t < t_stop - T_TOL_S)
        idx = np.flatnonzero(mask)
        if idx.size == 0 or not t_start < t_stop:
            raise ValueError(
                f"window [{t_start}, {t_stop}) holds no sample of {self.name} "
                f"(t from {self.t[0]} to {self.t[-1]} s)"
            )
        i0, i1 = int(idx[0]), int(idx[-1]) + 1
        new = dataclasses.replace(
            self,
            t=self.t[i0:i1],
            q_ref=self.q_ref[i0:i1],
            e_pulses=self.e_pulses[i0:i1],
            i_A=self.i_A[i0:i1],
            start_index=self.start_index + i0,
            window_s=(t_start, t_stop),
        )
        object.__setattr__(new, "sidecar", new._synced_sidecar())
        return new

    def _synced_sidecar(self) -> dict:
        """A deep copy of the sidecar with n_samples, window_s, trajectory and rig updated."""
        d = copy.deepcopy(dict(self.sidecar))
        d["n_samples"] = self.n_samples
        if self.window_s is None:
            d.pop("window_s", None)
        else:
            d["window_s"] = [float(self.window_s[0]), float(self.window_s[1])]
        traj = d.get("trajectory")
        traj = dict(traj) if isinstance(traj, Mapping) else {}
        traj["parameters"] = self.trajectory.to_parameters()
        d["trajectory"] = traj
        rig_into_sidecar(self.rig, d)
        return d

    def save(self, stem_path: str | os.PathLike) -> Path:
        """Write the log as ``STEM.csv`` + ``STEM.json``.

        Each file is written to a temporary file in the target directory and
        moved into place with :func:`os.replace`, so a reader never sees a
        partly written file. The sidecar is this log's sidecar with
        ``n_samples``, ``window_s``, ``trajectory.parameters`` and the rig
        values updated; floats are written with full (round-trip) precision,
        so ``load_log(log.save(p)) == log``.

        Parameters
        ----------
        stem_path : str or Path
            ``STEM``, ``STEM.csv`` or ``STEM.json``; the directory must exist.

        Returns
        -------
        Path
            The CSV file written.
        """
        csv_path, json_path, _ = _resolve(stem_path)
        out = io.StringIO()
        out.write(",".join(COLUMNS) + "\n")
        t = self.t.tolist()
        q = self.q_ref.tolist()
        e = self.e_pulses.tolist()
        i = self.i_A.tolist()
        out.write(
            "".join(
                f"{tk!r},{qk[0]!r},{qk[1]!r},{ek[0]},{ek[1]},{ik[0]!r},{ik[1]!r}\n"
                for tk, qk, ek, ik in zip(t, q, e, i)
            )
        )
        _atomic_write(csv_path, out.getvalue())
        _atomic_write(json_path, json.dumps(self._synced_sidecar(), indent=2) + "\n")
        return csv_path

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ExperimentLog):
            return NotImplemented
        return (
            self.start_index == other.start_index
            and self.window_s == other.window_s
            and np.array_equal(self.t, other.t)
            and np.array_equal(self.q_ref, other.q_ref)
            and np.array_equal(self.e_pulses, other.e_pulses)
            and np.array_equal(self.i_A, other.i_A)
            and self.rig == other.rig
            and self.trajectory == other.trajectory
            and self.sidecar == other.sidecar
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        win = f", window_s={self.window_s}" if self.window_s is not None else ""
        return (
            f"ExperimentLog(name={self.name!r}, n_samples={self.n_samples}, "
            f"start_index={self.start_index}{win}, path={str(self.path)!r})"
        )


def _atomic_write(path: Path, text: str) -> None:
    """Write ``text`` atomically with the policy of :mod:`plant.logs.fileio` (directory must exist)."""
    write_text_atomic(path, text)


# ------------------------------------------------------------------------ public API
def as_log(log) -> ExperimentLog:
    """A log as it is, or loaded from its path (the functions that take either).

    Parameters
    ----------
    log : ExperimentLog, str or path-like
        A loaded log, or the path of its CSV file (:func:`load_log`).

    Returns
    -------
    ExperimentLog

    Raises
    ------
    TypeError
        For anything else.
    LogError
        As :func:`load_log`, for a path.
    """
    if isinstance(log, ExperimentLog):
        return log
    if isinstance(log, (str, os.PathLike)):
        return load_log(log)
    raise TypeError(f"log must be a plant.ExperimentLog or a path, got {type(log).__name__}")


def load_log(path: str | os.PathLike) -> ExperimentLog:
    """Read and validate a rig log (``STEM.csv`` and its sidecar ``STEM.json``).

    Parameters
    ----------
    path : str or Path
        ``STEM.csv``, ``STEM.json`` or ``STEM``.

    Returns
    -------
    ExperimentLog
        ``t`` (n,) s, ``q_ref`` (n, 2) rad, ``e_pulses`` (n, 2) int64,
        ``i_A`` (n, 2) A, ``rig``, ``trajectory``, ``start_index`` = round(t[0]/Ts),
        ``window_s`` and the raw ``sidecar``.

    Raises
    ------
    LogError
        With a one-line message naming the file and the line, column or key,
        if: the CSV or sidecar is missing or unreadable; the sidecar is not
        valid JSON; the CSV is empty or has a header but no data rows; a
        column is missing, unexpected or duplicated; a row has the wrong
        number of fields; a value is non-numeric, NaN or inf; a pulse value
        is not an integer; t_k differs from k Ts by more than 1e-9 s; a
        sidecar key is missing, has the wrong shape or an invalid value (see
        :func:`rig_from_sidecar`, :meth:`Trajectory.from_sidecar`); a search
        range is inverted or empty; ``n_samples`` disagrees with the number of
        rows; ``window_s`` is invalid or does not contain the rows; or the
        q*_ref_rad columns differ from the sidecar's trajectory by more than
        1e-6 rad.
    """
    csv_path, json_path, stem = _resolve(path)
    cols = _read_csv(csv_path)
    sidecar = read_sidecar(json_path)
    rig = rig_from_sidecar(sidecar, json_path)
    trajectory = Trajectory.from_sidecar(sidecar, source=str(json_path))
    window_s = parse_window(sidecar, json_path)

    t = cols["t_s"]
    lines = cols["_lines"]
    n = t.shape[0]
    k = SidecarKeys(sidecar, json_path)
    n_declared = k.number("n_samples", integer=True, nonneg=True)
    if n_declared != n:
        raise k.err("n_samples", f"is {n_declared} but {csv_path.name} has {n} data rows")

    ts = rig.sample_time_s
    if t[0] < -T_TOL_S:
        raise sidecar_error(csv_path, f"line {lines[0]}, column 't_s': negative time {float(t[0])!r}")
    k0 = int(round(t[0] / ts))
    dev = np.abs(t - (k0 + np.arange(n)) * ts)
    bad = np.flatnonzero(dev > T_TOL_S)
    if bad.size:
        i = int(bad[0])
        raise sidecar_error(csv_path, f"line {lines[i]}, column 't_s': t = {float(t[i])!r} s is not k*Ts "
                             f"(expected {float((k0 + i) * ts)!r} with Ts = {ts!r} s)")
    if window_s is not None:
        if t[0] < window_s[0] - T_TOL_S or t[-1] >= window_s[1] + T_TOL_S:
            raise k.err("window_s", f"{list(window_s)} does not contain the rows "
                                    f"(t from {float(t[0])!r} to {float(t[-1])!r} s)")

    q_ref = np.column_stack([cols["q2_ref_rad"], cols["q3_ref_rad"]])
    q_traj = trajectory.position(t)
    diff = np.abs(q_ref - q_traj)
    worst = np.unravel_index(int(np.argmax(diff)), diff.shape)
    if diff[worst] > Q_REF_TOL_RAD:
        col = ("q2_ref_rad", "q3_ref_rad")[worst[1]]
        raise sidecar_error(json_path, f"trajectory in sidecar does not match q*_ref_rad columns "
                              f"(|diff| = {diff[worst]:.3g} rad > {Q_REF_TOL_RAD:g} at "
                              f"{csv_path.name} line {lines[worst[0]]}, column '{col}')")

    return ExperimentLog(
        path=csv_path,
        name=stem,
        t=t,
        q_ref=q_ref,
        e_pulses=np.column_stack([cols["e2_pulses"], cols["e3_pulses"]]),
        i_A=np.column_stack([cols["i2_A"], cols["i3_A"]]),
        rig=rig,
        trajectory=trajectory,
        start_index=k0,
        window_s=window_s,
        sidecar=sidecar,
    )


#: Bundled example logs: name -> (CSV stem in ``plant/data``, description).
EXAMPLES = {
    "paper_rigid": (
        _EXAMPLE_STEM,
        "the paper's experiment (eq. 6 reference, T = 3.65 s), rigid joints, no payload",
    ),
    "drill_flex": (
        "puma560_paper_drill_flex",
        "the same trajectory with a 1.5 kg drill at the flange, compliant gearboxes "
        "(a ~30 Hz mode) and noisy logged currents",
    ),
}

#: Name of the default bundled example.
DEFAULT_EXAMPLE = "paper_rigid"


def example_log_path(name: str = DEFAULT_EXAMPLE) -> Path:
    """Path of a bundled example log (its JSON sidecar is next to it).

    Two logs ship with the package, both 5215 samples at Ts = 0.7 ms of the
    paper's experiment (eq. 6 reference, T = 3.65 s):

    * ``"paper_rigid"`` (default): ``plant/data/puma560_paper_rigid.csv``,
      rigid joints, no payload;
    * ``"drill_flex"``: ``plant/data/puma560_paper_drill_flex.csv``, a 1.5 kg
      drill at the flange, compliant gearboxes (a lightly damped ~30 Hz
      mode the rigid model does not describe) and white noise on the logged
      currents; a log of a "real rig" for filtering and payload studies.

    The true parameters of these emulated logs are not shipped with the
    package: the library works from the log alone.

    Parameters
    ----------
    name : {'paper_rigid', 'drill_flex'}
        Which example (the keys of ``plant.logs.log.EXAMPLES``).

    Returns
    -------
    Path
        The example's ``STEM.csv``.

    Raises
    ------
    ValueError
        If ``name`` is not a bundled example; the one-line message lists the
        names.

    Examples
    --------
    >>> from plant.logs.log import example_log_path
    >>> example_log_path().name
    'puma560_paper_rigid.csv'
    >>> example_log_path("drill_flex").name
    'puma560_paper_drill_flex.csv'
    """
    if not isinstance(name, str) or name not in EXAMPLES:
        raise ValueError(f"unknown example log {name!r}; choose one of "
                         f"{', '.join(repr(k) for k in EXAMPLES)}")
    return Path(__file__).resolve().parents[1] / "data" / f"{EXAMPLES[name][0]}.csv"


def load_example(name: str = DEFAULT_EXAMPLE) -> ExperimentLog:
    """Load a bundled example log (see :func:`example_log_path`).

    Parameters
    ----------
    name : {'paper_rigid', 'drill_flex'}
        Which example; default the rigid paper log.

    Returns
    -------
    ExperimentLog

    Raises
    ------
    ValueError
        If ``name`` is not a bundled example.

    Examples
    --------
    >>> import plant
    >>> plant.load_example().n_samples
    5215
    >>> plant.load_example("drill_flex").rig.payload_mass_kg
    1.5
    """
    return load_log(example_log_path(name))
