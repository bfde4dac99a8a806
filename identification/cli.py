"""Command-line interface: ``python -m identification LOG.csv ...`` (also ``puma-identify``).

Identifies the base parameters f1..f9 from a rig log (CSV + JSON sidecar),
prints them as a table with their units and the output error of paper eq. 4,
and optionally writes the result as JSON and the convergence and
tracking-error plots as PNG::

    python -m identification LOG.csv --seed S --output OUT.json --plot DIR
    python -m identification --example            # the bundled paper log

Exit status
-----------
0
    Success.
1
    A bad log or a bad option value: one line ``error: ...`` on stderr, no
    traceback, and no output file.
2
    A command-line usage error (argparse's own message).
130
    Interrupted by Ctrl-C.  The first Ctrl-C stops the search after the
    current GA generation (or refinement start); the best result so far is
    then printed and written as usual (``"interrupted": true`` in the JSON,
    and the plots).  A second Ctrl-C aborts at once; if no result exists yet
    the single line ``error: interrupted ...`` is printed and nothing is
    written.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

__all__ = ["main", "build_parser", "format_result_table"]

#: Exit status of a run stopped by Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130


class CLIError(Exception):
    """A bad option or input detected by the CLI itself (exit status 1)."""


def _lowpass_arg(text):
    """argparse type of --lowpass: a frequency in Hz or 'auto'."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frequency in Hz or 'auto', got {text!r}")


def build_parser():
    """The argument parser of ``python -m identification``.

    Returns
    -------
    argparse.ArgumentParser
    """
    from .api import DEFAULT_METHOD, METHODS

    p = argparse.ArgumentParser(
        prog="python -m identification",
        description=(
            "Identify the base parameters f1..f9 of PUMA 560 links 2-3 from a "
            "position-only P-control log (CSV + JSON sidecar with the same stem) "
            "with the paper's multi-population GA (then prediction-error "
            "refinement, the default method)."
        ),
        epilog=(
            "Exit status: 0 success; 1 bad log or option (one line 'error: ...' on "
            "stderr, no output file); 2 usage error; 130 interrupted by Ctrl-C (the "
            "best result so far is still written)."
        ),
    )
    p.add_argument("log", nargs="?", metavar="LOG.csv",
                   help="the log's CSV (its sidecar STEM.json must be next to it)")
    p.add_argument("--example", action="store_true",
                   help="run on the bundled example log (the paper's experiment, "
                        "plant/data/puma560_paper_rigid.csv) instead of LOG.csv")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of the random generator (default 0); the same seed "
                        "gives the same result bit for bit")
    p.add_argument("--output", "-o", metavar="OUT.json",
                   help="write the result as JSON (atomically)")
    p.add_argument("--plot", metavar="DIR",
                   help="write convergence.png and tracking_errors.png into DIR")
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"'{DEFAULT_METHOD}' (default): the GA, then prediction-error "
                        "refinement; 'paper': the paper's GA alone")
    p.add_argument("--generations", type=int, metavar="N",
                   help="GA generations (default: the paper's 40); fewer for a quick look")
    p.add_argument("--workers", type=int, metavar="N",
                   help="threads of the parallel simulation (default: all cores)")
    p.add_argument("--lowpass", type=_lowpass_arg, metavar="HZ|auto",
                   help="low-pass the logged and the simulated tracking errors with the "
                        "same zero-phase filter at HZ before comparing them (logs with "
                        "joint-flexibility oscillations); 'auto' takes the cutoff that "
                        "identification.diagnostics.suggest_lowpass finds in the error "
                        "spectrum (none for a log without such a mode)")
    p.add_argument("--consistent", action="store_true",
                   help="enforce f3 = a3 f5 and f4 = a3 f6 (eq. 3; a3 from the sidecar) and "
                        "search the 7 other base parameters (recommended for flexible "
                        "robots)")
    p.add_argument("--payload", action="store_true",
                   help="identify a payload at the flange on top of the robot's f from "
                        "--prior (on-line payload identification); needs --prior")
    p.add_argument("--prior", metavar="PRIOR.json",
                   help="result file of an earlier identification of the unloaded "
                        "robot (its \"f\" list); used with --payload")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bar or status lines")
    return p


# --------------------------------------------------------------------------- helpers
def _one_line(msg) -> str:
    text = " ".join(str(msg).split())
    return text or "unknown error"


def _check_writable_target(path: Path, what: str, *, want_dir: bool) -> None:
    """Fail early (before a long run) if ``path`` cannot be written later."""
    if path.exists():
        if want_dir and not path.is_dir():
            raise CLIError(f"{what} {path} exists and is not a directory")
        if not want_dir and path.is_dir():
            raise CLIError(f"{what} {path} is a directory")
    parent = path if (want_dir and path.is_dir()) else path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise CLIError(f"cannot create {what} {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CLIError(f"cannot write {what} {path}: {parent} is not writable")


def _load_prior(path) -> np.ndarray:
    """The ``"f"`` list (9 finite numbers) of an earlier result file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CLIError(f"{p}: prior result file not found") from None
    except IsADirectoryError:
        raise CLIError(f"{p}: prior result file is a directory") from None
    except (OSError, UnicodeDecodeError) as e:
        raise CLIError(f"{p}: cannot read prior result file ({e})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise CLIError(f"{p}: invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    f = data.get("f") if isinstance(data, dict) else None
    if (not isinstance(f, list) or len(f) != 9
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in f)):
        raise CLIError(f"{p}: key 'f' must be a list of 9 finite numbers (f1..f9)")
    return np.array(f, dtype=float)


def _validate(args) -> None:
    if args.example and args.log:
        raise CLIError("give either LOG.csv or --example, not both")
    if not args.example and not args.log:
        raise CLIError("no log given: pass LOG.csv or --example")
    if args.seed < 0:
        raise CLIError(f"--seed must be >= 0, got {args.seed}")
    if args.generations is not None and args.generations < 1:
        raise CLIError(f"--generations must be >= 1, got {args.generations}")
    if args.workers is not None and args.workers < 1:
        raise CLIError(f"--workers must be >= 1, got {args.workers}")
    if args.lowpass not in (None, "auto") and not (math.isfinite(args.lowpass)
                                                   and args.lowpass > 0):
        raise CLIError(f"--lowpass must be a positive frequency in Hz, got {args.lowpass}")
    if args.payload and not args.prior:
        raise CLIError("--payload requires --prior PRIOR.json (a result file of the unloaded robot)")
    if args.prior and not args.payload:
        raise CLIError("--prior is only used with --payload")


def format_result_table(result, log=None) -> str:
    """The identified f1..f9 with units, and the output error, as text.

    Parameters
    ----------
    result : IdentificationResult
    log : plant.ExperimentLog, optional
        For the header line (default: the log attached to ``result``).

    Returns
    -------
    str
        Several lines, no trailing newline.
    """
    from plant import F_NAMES, F_UNITS

    log = log if log is not None else result.get("log")
    n = f" ({log.n_samples} samples)" if log is not None else ""
    lines = [
        f"log: {result.get('log_name')}{n}   method: {result.method}   "
        f"seed: {result.get('seed')}",
        f"{'param':<6}{'value':>14}  unit",
    ]
    for name, unit, v in zip(F_NAMES, F_UNITS, np.asarray(result.f, dtype=float)):
        lines.append(f"{name:<6}{v:>14.6g}  {unit}")
    payload = result.get("payload")
    if payload:
        for k, v in payload.items():
            val = f"{v:.6g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)
            lines.append(f"payload {k}: {val}")
    lines.append(f"output error Y (eq. 4): {result.objective:.6g} pulses^2")
    lines.append(f"simulations: {result.evaluations}   wall time: {result.wall_time_s:.2f} s")
    if result.interrupted:
        lines.append(f"INTERRUPTED: {result.message} (best so far)")
    return "\n".join(lines)


class _GracefulInterrupt:
    """Context manager turning the first Ctrl-C into a clean stop.

    The first SIGINT only sets :attr:`requested`; the identification's
    callback returns it, so the search stops after the current GA generation
    (or refinement start) and returns the best result so far, which is then
    printed and written.  The handler is then the default one again, so a
    second Ctrl-C raises KeyboardInterrupt at once.  (An interrupt raised
    inside the compiled parallel kernels is otherwise not always delivered as
    a KeyboardInterrupt.)  Outside the main thread nothing is installed.
    """

    def __init__(self, stream, quiet=False):
        self.stream = stream
        self.quiet = quiet
        self.requested = False
        self._old = None

    def _handler(self, signum, frame):
        import signal

        self.requested = True
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if not self.quiet:
            print("\nCtrl-C: stopping after the current step and writing the best result "
                  "so far (Ctrl-C again to abort)", file=self.stream, flush=True)

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
            self._old = None
        return False


def _is_wrapped_interrupt(exc) -> bool:
    """A KeyboardInterrupt that surfaced as another exception (e.g. numba's SystemError)."""
    seen = set()
    e = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _save_plots(result, directory: Path) -> list:
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, fig in (("convergence.png", result.plot()),
                      ("tracking_errors.png", result.plot_tracking_errors())):
        path = directory / name
        fig.savefig(path, dpi=120)  # Figure objects render with Agg; nothing is shown
        paths.append(path)
    return paths


def _run(args, stdout, stderr) -> int:
    import plant

    from .api import identify

    _validate(args)
    prior = _load_prior(args.prior) if args.prior else None
    log_path = plant.example_log_path() if args.example else Path(args.log)
    log = plant.load_log(log_path)
    if args.lowpass == "auto":
        from .diagnostics import suggest_lowpass

        args.lowpass = suggest_lowpass(log)
        if not args.quiet:
            cut = "none (no oscillation mode found)" if args.lowpass is None else \
                f"{args.lowpass:.3g} Hz"
            print(f"low-pass cutoff (auto): {cut}", file=stderr, flush=True)
    if args.lowpass is not None:
        from .filtering import lowpass_sos

        lowpass_sos(args.lowpass, log.rig.sample_time_s)  # cutoff below Nyquist
    out = Path(args.output) if args.output else None
    plot_dir = Path(args.plot) if args.plot else None
    if out is not None:
        _check_writable_target(out, "output file", want_dir=False)
    if plot_dir is not None:
        _check_writable_target(plot_dir, "plot directory", want_dir=True)

    kwargs = dict(method=args.method, rng=args.seed, workers=args.workers,
                  progress=not args.quiet, lowpass_hz=args.lowpass)
    if args.generations is not None:
        kwargs["ga_options"] = {"n_gen": args.generations}
    if args.payload:
        kwargs.update(payload=True, prior=prior)
    elif args.consistent:
        kwargs.update(consistent=True)

    ctrl_c = _GracefulInterrupt(stderr, quiet=args.quiet)

    def status(r):
        if not args.quiet and r.get("stage") == "refine":
            print(f"refinement: start done, prediction-error cost {r.fun:.6g} pulses^2",
                  file=stderr, flush=True)
        return ctrl_c.requested

    if not args.quiet:
        print(f"identifying {log.name} ({log.n_samples} samples), method {args.method}, "
              f"seed {args.seed}", file=stderr, flush=True)
    with ctrl_c:
        result = identify(log, callback=status, **kwargs)
    if ctrl_c.requested and result.interrupted:
        result["message"] = result.message.replace("stopped by callback", "interrupted by Ctrl-C")

    print(format_result_table(result, log), file=stdout, flush=True)
    if out is not None:
        result.save_json(out)
        if not args.quiet:
            print(f"wrote {out}", file=stderr)
    if plot_dir is not None:
        for path in _save_plots(result, plot_dir):
            if not args.quiet:
                print(f"wrote {path}", file=stderr)
    return EXIT_INTERRUPTED if result.interrupted else 0


def main(argv=None) -> int:
    """Entry point of ``python -m identification`` and ``puma-identify``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 success, 1 bad log or option (one ``error:`` line on
        stderr, no output file), 2 usage error (raised by argparse as
        ``SystemExit``), 130 interrupted (the best result so far is written).
    """
    import plant

    args = build_parser().parse_args(argv)
    stdout, stderr = sys.stdout, sys.stderr
    try:
        return _run(args, stdout, stderr)
    except KeyboardInterrupt:
        print("error: interrupted before a result was available (nothing written)",
              file=stderr)
        return EXIT_INTERRUPTED
    except (CLIError, plant.LogError, plant.SimulationError, ValueError, OSError) as e:
        print(f"error: {_one_line(e)}", file=stderr)
        return 1
    except SystemError as e:
        if not _is_wrapped_interrupt(e):
            raise
        print("error: interrupted before a result was available (nothing written)",
              file=stderr)
        return EXIT_INTERRUPTED
