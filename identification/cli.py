"""Command-line interface: ``python -m identification LOG.csv ...`` (also ``puma-identify``).

Identifies the base parameters f1..f9 from a rig log (CSV + JSON sidecar),
prints them as a table with their units and the output error of paper eq. 4,
and optionally writes the result as JSON and the convergence and
tracking-error plots as PNG::

    python -m identification LOG.csv --seed S --output OUT.json --plot DIR
    python -m identification --example            # the bundled paper log

The output error printed, written to the JSON (``fun`` = ``objective_pulses2``)
and shown in the titles of the plots is one number, at the identification's
integration setting (``settings.substeps`` RK4 steps per sample, and its
low-pass filter if any); the table and the titles say which setting.

Output files
------------
All files are written atomically with the policy of :mod:`plant.logs.fileio`, and
every target is checked before the identification starts (a bad one fails at
once, exit status 1, nothing written):

* a target that exists and is not a regular file (``/dev/full``, a FIFO, a
  directory, a socket) is refused;
* a symlink is written through: its target is replaced, the link is kept;
* an existing file keeps its permission bits; a new one gets
  ``0o666 & ~umask``;
* a missing directory (of ``--output`` or ``--plot``) is created, and the
  CLI says so on stderr (``created directory ...``, unless ``--quiet``);
* the input log's own files are never overwritten.

Progress
--------
On a terminal, a tqdm bar shows the GA's generations.  When stderr is not a
terminal (a log file, a pipe) there is no bar and no carriage return: a plain
line per GA generation at most every :data:`STATUS_INTERVAL_S` seconds.  In
both cases one line per refinement start gives its number and its
prediction-error cost.  ``--quiet`` silences all of these.

Exit status
-----------
0
    Success.
1
    A bad log or a bad option value: one line ``error: ...`` on stderr, no
    traceback, and no output file.  A log whose signals cannot carry an
    identification (:func:`plant.logs.sanity.check_experiment`) is refused the
    same way, before any work.  A write that fails after an earlier output
    was completed (the JSON, then a plot on a full disk) names the files
    already written in that line.
2
    A command-line usage error (argparse's own message).
130
    Interrupted by Ctrl-C.  The first Ctrl-C during the search stops it after
    the current GA generation (or refinement start); the best result so far
    is then printed and written as usual (``"interrupted": true`` in the
    JSON, and the plots).  A second Ctrl-C aborts at once.  A Ctrl-C at any
    other time (while importing, compiling the numerical kernels, loading
    the log or writing files), or when no result exists yet, ends with the
    single line ``error: interrupted ...`` on stderr and no traceback;
    files are then either complete or not written at all.  A Ctrl-C that
    arrives while Python runs a finaliser or a ctypes callback (where it can
    only be printed as "Exception ignored"), or that C code clears on its
    way up, is remembered (``identification.sigint``) and honoured at the
    next checkpoint: before the search, after each search step, and before
    any output is written.  A run that has not ended
    ``identification.sigint.GRACE_S`` (60) seconds after a Ctrl-C is ended
    by a watchdog with the one ``error: interrupted`` line and exit
    status 130.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from . import sigint
from .ga import PAPER_GA

__all__ = ["main", "build_parser", "format_result_table"]

#: Exit status of a run stopped by Ctrl-C (128 + SIGINT): :data:`identification.sigint.EXIT_INTERRUPTED`.
EXIT_INTERRUPTED = sigint.EXIT_INTERRUPTED

#: The one line printed on stderr when Ctrl-C ends the run without a result.
INTERRUPTED_LINE = "error: interrupted (nothing written)"

#: Least seconds between two GA status lines when stderr is not a terminal.
STATUS_INTERVAL_S = 10.0

#: Names of the plot files written into --plot DIR.
PLOT_FILES = ("convergence.png", "tracking_errors.png")


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

    script = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    p = argparse.ArgumentParser(
        # the installed script says its own name; python -m identification says that
        prog="puma-identify" if script == "puma-identify" else "python -m identification",
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
                   help="write the result as JSON (atomically; an existing file keeps its "
                        "permissions, a symlink is written through, a device, FIFO or "
                        "directory is refused, a missing directory is created)")
    p.add_argument("--plot", metavar="DIR",
                   help="write convergence.png and tracking_errors.png into DIR (created "
                        "if missing; same rules as --output)")
    p.add_argument("--method", choices=METHODS, default=None,
                   help=f"'{DEFAULT_METHOD}' (default): the GA, then prediction-error "
                        "refinement; 'paper': the paper's GA alone.  A robot-model log "
                        "(a 'robot' object in its sidecar) defaults to IDIM-LS, then "
                        "prediction-error refinement, and takes every other method too; "
                        "'idim-ls' and 'idim-iv': the classical inverse-model estimate alone")
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
    p.add_argument("--model", choices=("rigid", "flexible", "auto"), default="auto",
                   help="robot model: rigid, two-mass flexible joints, or auto (default): "
                        "rigid when its prediction errors sit at the encoder's quantisation "
                        "floor, otherwise flexible when the flexible fit predicts held-back "
                        "samples better (at half the cost, significantly, at the floor, or "
                        "with half the excess over it: one rule for every robot), with "
                        "gearbox backlash when that improves it again; a model still far "
                        "above the floor is reported as inadequate (the result's model_choice "
                        "says why)")
    p.add_argument("--consistent", action="store_true",
                   help="enforce f3 = a3 f5 and f4 = a3 f6 (eq. 3; a3 from the sidecar) and "
                        "search the 7 other base parameters (recommended for flexible "
                        "robots)")
    p.add_argument("--payload", action="store_true",
                   help="identify a payload at the flange on top of the robot's f from "
                        "--prior (on-line payload identification); needs --prior.  On a "
                        "robot-model log: a point mass on the last link over the whole log "
                        "(identification.arm_payload.identify_arm_payload)")
    p.add_argument("--prior", metavar="PRIOR.json",
                   help="result file of an earlier identification of the unloaded "
                        "robot (its \"f\" list; for a robot-model log, the unloaded arm's "
                        "--output file, rigid or flexible); used with --payload")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bar or status lines (the progress bar is only shown "
                        "when stderr is a terminal)")
    return p


# --------------------------------------------------------------------------- helpers
def _one_line(msg) -> str:
    text = " ".join(str(msg).split())
    return text or "unknown error"


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def _result_setting(result) -> str:
    """The integration setting of ``fun`` as text (e.g. '1 RK4 step/sample (identification)')."""
    if hasattr(result, "setting_text"):
        return result.setting_text()
    from .result import describe_setting

    settings = result.get("settings") or {}
    n = settings.get("substeps")
    if n is None:
        return "the identification's setting"
    return describe_setting(n, settings.get("lowpass_hz"), identification_substeps=n)


def _check_output_targets(out, plot_dir, inputs):
    """Check every output file before the run (plant.logs.fileio policy); write nothing.

    Returns the list of :class:`plant.logs.fileio.OutputTarget` (JSON first, then
    the PNGs).  Raises CLIError / OutputFileError with one line.
    """
    from plant.logs.fileio import check_output_path

    targets = []
    if out is not None:
        targets.append(("--output", check_output_path(out, create_dirs=True)))
    if plot_dir is not None:
        if plot_dir.exists() and not plot_dir.is_dir():
            raise CLIError(f"plot directory {plot_dir} exists and is not a directory")
        for name in PLOT_FILES:
            targets.append(("--plot", check_output_path(plot_dir / name, create_dirs=True)))
    seen = {}
    for opt, t in targets:
        real = os.path.realpath(t.target)
        for inp in inputs:
            if inp is not None and os.path.realpath(inp) == real:
                raise CLIError(f"{opt} {t.path} would overwrite the input file {inp}")
        if real in seen:
            raise CLIError(f"{opt} {t.path} and {seen[real]} are the same file")
        seen[real] = t.path
    return [t for _, t in targets]


def _load_prior(path) -> np.ndarray:
    """The ``"f"`` list (9 finite numbers) of an earlier result file."""
    from .parameters import prior_f

    try:
        return prior_f(Path(path))
    except ValueError as e:
        raise CLIError(str(e)) from None


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
    if args.output is not None and not str(args.output).strip():
        raise CLIError("--output needs a file name (got an empty string)")
    if args.plot is not None and not str(args.plot).strip():
        raise CLIError("--plot needs a directory name (got an empty string)")
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
        Several lines, no trailing newline.  The output error line gives
        ``fun`` and its integration setting (RK4 steps per sample, low-pass
        filter), e.g. ``output error Y (eq. 4): 1175 pulses^2 at 1 RK4
        step/sample (identification)``.
    """
    from plant import F_NAMES, F_UNITS

    log = log if log is not None else result.get("log")
    n = f" ({log.n_samples} samples)" if log is not None else ""
    std = result.get("f_std")  # the ± column (issue 15), when standard errors exist
    std = [None] * 9 if std is None else np.asarray(std, dtype=float)
    pm = "" if std[0] is None else f"{'± std':>12}"
    lines = [
        f"log: {result.get('log_name')}{n}   method: {result.get('method')}   "
        f"seed: {result.get('seed')}",
        f"{'param':<6}{'value':>14}{pm}  unit",
    ]
    for name, unit, v, sd in zip(F_NAMES, F_UNITS, np.asarray(result["f"], dtype=float), std):
        lines.append(f"{name:<6}{v:>14.6g}" + ("" if sd is None else f"  ± {sd:<8.2g}")
                     + f"  {unit}")
    from .flexible import joint_range_lines

    lines.extend(joint_range_lines(result.get("joint_intervals")))
    payload = result.get("payload")
    if payload:
        for k, v in payload.items():
            val = f"{v:.6g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)
            lines.append(f"payload {k}: {val}")
    lines.append(f"output error Y (eq. 4): {float(result.fun):.6g} pulses^2 "
                 f"at {_result_setting(result)}")
    nit = result.get("nit")
    nit = f"   iterations: {nit}" if nit is not None else ""
    lines.append(f"simulations: {result.nfev}{nit}   "
                 f"wall time: {float(result.get('wall_time_s') or 0.0):.2f} s")
    if result.get("poorly_excited"):
        from .api import excitation_text

        lines.append("warning: " + excitation_text(result))
    if result.get("interrupted"):
        lines.append(f"INTERRUPTED: {result.get('message')} (best so far)")
    return "\n".join(lines)


class _GracefulInterrupt:
    """Context manager turning the first Ctrl-C into a clean stop.

    The first SIGINT only sets :attr:`requested`; the identification's
    callback returns it, so the search stops after the current GA generation
    (or refinement start) and returns the best result so far, which is then
    printed and written.  The handler is then the previous one again (Python's
    default, or :mod:`identification.sigint`'s recording one), so a second
    Ctrl-C raises KeyboardInterrupt at once.  (An interrupt raised
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
        sigint.note()  # the watchdog's grace starts (a process of its own)
        again = self._old if callable(self._old) else signal.default_int_handler
        signal.signal(signal.SIGINT, again)
        if not self.quiet:
            nl = "\n" if _isatty(self.stream) else ""  # end a tqdm bar's line
            print(f"{nl}Ctrl-C: stopping after the current step and writing the best result "
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


class _Status:
    """The CLI's status lines on stderr, and the callback of identify().

    Never a carriage return: one line per refinement start and, when stderr
    is not a terminal (no tqdm bar then), one line per GA generation at most
    every :data:`STATUS_INTERVAL_S` seconds (and the first and last ones).
    """

    def __init__(self, stream, quiet, ctrl_c, n_gen=None):
        self.stream = stream
        self.quiet = quiet
        self.ctrl_c = ctrl_c
        self.n_gen = n_gen
        self.tty = _isatty(stream)
        self.refine_count = 0
        self._last_ga = None

    def say(self, text):
        if not self.quiet:
            print(text, file=self.stream, flush=True)

    def __call__(self, r):
        """identify()'s callback: print a status line, return True after a Ctrl-C."""
        import time

        stage = r.get("stage")
        if stage == "refine":
            self.refine_count += 1
            start = r.get("start") or self.refine_count
            n = r.get("n_starts")
            of = f"/{n}" if n else ""
            self.say(f"refinement start {start}{of}: prediction-error cost "
                     f"{float(r.get('fun')):.6g} pulses^2")
        elif stage == "model" and r.get("step"):  # identify_arm's model choice, fit by fit
            if r.get("start") is None:
                self.say(f"{r['step']} ...")
            else:
                self.say(f"  start {r['start']}/{r.get('n_starts')}: prediction-error cost "
                         f"{float(r.get('fun')):.6g} pulses^2")
        elif stage == "ga" and not self.tty:
            gen = r.get("generation")
            now = time.monotonic()
            last = gen is not None and self.n_gen is not None and gen >= self.n_gen
            if self._last_ga is None or last or now - self._last_ga >= STATUS_INTERVAL_S:
                self._last_ga = now
                of = f"/{self.n_gen}" if self.n_gen else ""
                g = "" if gen is None else f" {gen}{of}"
                self.say(f"GA generation{g}: best output error {float(r.get('fun')):.6g} "
                         "pulses^2")
        if sigint.seen():
            self.ctrl_c.requested = True
        return self.ctrl_c.requested


def _wrote(status, info, what="wrote"):
    for d in info.created_dirs:
        status.say(f"created directory {d}")
    via = f" (through the symlink, into {info.target})" if info.via_symlink else ""
    status.say(f"{what} {info.path}{via}")


def _save_plots(result, directory: Path, status, written=None) -> list:
    """Write PLOT_FILES into ``directory`` atomically (plant.logs.fileio policy).

    ``written`` (a list) receives each path once it is complete.
    """
    from plant.logs.fileio import atomic_output, check_output_path

    paths = []
    for name, make in zip(PLOT_FILES, (result.plot, result.plot_tracking_errors)):
        fig = make()  # Figure objects render with Agg; nothing is shown
        path = directory / name
        info = check_output_path(path, create_dirs=True)  # what the write below does
        with atomic_output(path, create_dirs=True) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
        _wrote(status, info)
        paths.append(path)
        if written is not None:
            written.append(str(path))
    return paths


def _run(args, stdout, stderr) -> int:
    import plant

    from . import api
    from .uncertainty import PoorExcitationWarning

    _validate(args)
    out = Path(args.output) if args.output else None
    plot_dir = Path(args.plot) if args.plot else None
    log_path = plant.example_log_path() if args.example else Path(args.log)
    inputs = [log_path, log_path.with_suffix(".json"), log_path.with_suffix(".csv"),
              args.prior]
    _check_output_targets(out, plot_dir, [p for p in inputs if p is not None])
    if not args.example and _is_robot_model_log(log_path):
        return _run_arm(args, log_path, out, plot_dir, stdout, stderr)
    if args.method is None:
        args.method = api.DEFAULT_METHOD
    prior = _load_prior(args.prior) if args.prior else None
    log = plant.load_log(log_path)
    from plant.logs.sanity import check_experiment  # identify() checks too; here before any output

    check_experiment(log, n_parameters=4 if args.payload else 9 + len(log.rig.unknown_friction))
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

    # tqdm's bar only on a terminal (no carriage returns in a log file)
    kwargs = dict(method=args.method, rng=args.seed, workers=args.workers,
                  progress=not args.quiet and _isatty(stderr), lowpass_hz=args.lowpass,
                  model=args.model)
    if args.generations is not None:
        kwargs["ga_options"] = {"n_gen": args.generations}
    if args.payload:
        kwargs.update(payload=True, prior=prior)
    elif args.consistent:
        kwargs.update(consistent=True)

    ctrl_c = _GracefulInterrupt(stderr, quiet=args.quiet)
    n_gen = args.generations or PAPER_GA["n_gen"]
    status = _Status(stderr, args.quiet, ctrl_c, n_gen=n_gen)
    status.say(f"identifying {log.name} ({log.n_samples} samples), method {args.method}, "
               f"seed {args.seed}")
    if hasattr(plant, "warm_up"):  # compile the numerical kernels once, saying so
        plant.warm_up(announce=None if args.quiet else status.say, closed_loop=False)
    if sigint.seen():  # a Ctrl-C that a finaliser swallowed: nothing has been searched yet
        raise KeyboardInterrupt
    with ctrl_c, warnings.catch_warnings():  # the table's warning line says it
        warnings.simplefilter("ignore", PoorExcitationWarning)
        warnings.simplefilter("ignore", api.ModelInadequacyWarning)  # said below
        warnings.simplefilter("ignore", api.SearchBoundWarning)  # said below
        result = api.identify(log, callback=status, **kwargs)
    if sigint.seen() and not result.get("interrupted"):
        raise KeyboardInterrupt  # swallowed after the last step: never write over an output
    if ctrl_c.requested and result.get("interrupted"):
        result["message"] = str(result.get("message", "")).replace(
            "stopped by callback", "interrupted by Ctrl-C")

    print(format_result_table(result, log), file=stdout, flush=True)
    choice = result.get("model_choice") or {}
    if choice.get("reason") and not args.quiet:
        status.say(f"model: {result.get('model', 'rigid')} ({choice['reason']})")
    for text in result.get("warnings") or []:
        print(f"warning: {text}", file=stderr, flush=True)
    if result.get("at_bounds"):
        print(f"warning: {api.bounds_text(result['at_bounds'])}", file=stderr, flush=True)
    if not result.get("success", True) and not result.get("interrupted"):
        # a diverged or rejected fit is never written as a result (issue 20)
        raise CLIError(f"no valid result: {result.get('message', '')}")
    if out is not None:
        _wrote(status, result.save_json(out, create_dirs=True))
        args.written.append(str(out))
    if plot_dir is not None:
        _save_plots(result, plot_dir, status, args.written)
    return EXIT_INTERRUPTED if result.get("interrupted") else 0


def _is_robot_model_log(log_path) -> bool:
    """Whether the log's sidecar names a robot model (a ``robot`` object; :mod:`plant.logs.arm_log`)."""
    from plant.logs.arm_log import is_arm_sidecar
    from plant.logs.sidecar import read_sidecar

    side = Path(log_path).with_suffix(".json")
    if not side.is_file():
        return False  # plant.load_log says what is missing
    return is_arm_sidecar(read_sidecar(side))


def _run_arm(args, log_path, out, plot_dir, stdout, stderr) -> int:
    """The CLI on a robot model's log: :func:`identification.arm.identify_arm`."""
    from plant.logs.arm_log import load_arm_log
    from plant.logs.fileio import atomic_output, check_output_path

    from plant.simulation.arm import kernels_cached
    from plant.simulation.generated import kernel_directory

    from .arm import ARM_DEFAULT_METHOD, identify_arm

    unsupported = [opt for opt, on in (("--consistent", args.consistent),
                                       ("--lowpass", args.lowpass is not None)) if on]
    if unsupported:
        raise CLIError(f"{', '.join(unsupported)} is for PUMA 560 links 2-3 logs; {log_path} "
                       "names a robot model")
    if args.payload:
        return _run_arm_payload(args, log_path, out, plot_dir, stdout, stderr)
    method = args.method or ARM_DEFAULT_METHOD  # every --method choice is identify_arm's too
    ctrl_c = _GracefulInterrupt(stderr, quiet=args.quiet)
    n_gen = args.generations or PAPER_GA["n_gen"]
    status = _Status(stderr, args.quiet, ctrl_c, n_gen=n_gen)
    log = load_arm_log(log_path)
    status.say(f"identifying {log.name} ({log.n_samples} samples, {log.model.name}, "
               f"joints {', '.join(log.joint_names)}), method {method}, seed {args.seed}")
    if not kernels_cached(log.model, lane_friction=bool(log.rig.unknown_friction)):
        status.say(f"generating and compiling {log.model.name}'s kernels once (a minute or more "
                   f"for a new robot; cached in {kernel_directory()})")
    ga_options = {"n_gen": args.generations} if args.generations is not None else None
    if sigint.seen():  # a Ctrl-C that a finaliser swallowed: nothing has been searched yet
        raise KeyboardInterrupt
    with ctrl_c:
        result = identify_arm(log, method=method, rng=args.seed, ga_options=ga_options,
                              workers=args.workers, model=args.model, callback=status,
                              progress=not args.quiet and _isatty(stderr))
    if sigint.seen() and not result.get("interrupted"):
        raise KeyboardInterrupt  # swallowed after the last step: never write over an output
    if ctrl_c.requested and result.get("interrupted"):
        result.message = str(result.message).replace("stopped by callback", "interrupted by Ctrl-C")
    print(f"log: {log.name} ({log.n_samples} samples)   robot: {log.model.name}   method: {method}"
          f"   seed: {args.seed}", file=stdout)
    print(result.table(), file=stdout, flush=True)
    choice = result.get("model_choice")
    if choice:
        print(f"model: {choice.get('model', result.model)} ({choice.get('reason', '')})", file=stdout)
    for w in result.get("warnings") or []:
        print(f"warning: {w}", file=stdout, flush=True)
    if result.get("interrupted"):
        print(f"INTERRUPTED: {result.message} (best so far)", file=stdout, flush=True)
    if not result.success:
        raise CLIError(f"no valid result: {result.message}")
    if out is not None:
        _wrote(status, result.save_json(out, create_dirs=True))
        args.written.append(str(out))
    if plot_dir is not None:
        path = plot_dir / "tracking_errors.png"
        info = check_output_path(path, create_dirs=True)
        with atomic_output(path, create_dirs=True) as tmp:
            result.plot(log).savefig(tmp, dpi=120, format="png")
        _wrote(status, info)
        args.written.append(str(path))
    return EXIT_INTERRUPTED if result.get("interrupted") else 0


def _run_arm_payload(args, log_path, out, plot_dir, stdout, stderr) -> int:
    """``--payload --prior`` on a robot model's log: a payload on the last link over the whole
    log (:func:`identification.arm_payload.identify_arm_payload`) on top of the unloaded arm
    of the prior's result file (:func:`identification.arm_payload.prior_from_file`)."""
    import json

    from plant.logs.arm_log import load_arm_log
    from plant.logs.fileio import atomic_output, check_output_path, write_text_atomic
    from plant.simulation.arm import kernels_cached
    from plant.simulation.generated import kernel_directory

    from .arm_payload import identify_arm_payload, prior_from_file

    given = [opt for opt, on in (("--method", args.method is not None),
                                 ("--generations", args.generations is not None),
                                 ("--model", args.model != "auto")) if on]
    if given:
        raise CLIError(f"{', '.join(given)} does not apply to --payload on a robot model's log "
                       "(the arm is the prior's; only the payload is searched)")
    status = _Status(stderr, args.quiet, None, n_gen=None)
    log = load_arm_log(log_path)
    prior = prior_from_file(args.prior, log)
    status.say(f"identifying a payload on {log.model.name}'s last link from {log.name} "
               f"({log.n_samples} samples), prior {args.prior} ({prior['model']})")
    if not kernels_cached(log.model, lane_friction=False):
        status.say(f"generating and compiling {log.model.name}'s kernels once (a minute or more "
                   f"for a new robot; cached in {kernel_directory()})")
    result = identify_arm_payload(log, prior, workers=args.workers)
    print(f"log: {log.name} ({log.n_samples} samples)   robot: {log.model.name}   payload on "
          f"the last link, prior: {args.prior}", file=stdout)
    print(result.table(), file=stdout, flush=True)
    if not result.success:
        raise CLIError(f"no valid result: {result.message}")
    if out is not None:
        _wrote(status, write_text_atomic(out, json.dumps(result.to_dict(), indent=1) + "\n",
                                         create_dirs=True))
        args.written.append(str(out))
    if plot_dir is not None:
        path = plot_dir / "payload_residuals.png"
        info = check_output_path(path, create_dirs=True)
        with atomic_output(path, create_dirs=True) as tmp:
            result.plot().get_figure().savefig(tmp, dpi=120, format="png")
        _wrote(status, info)
        args.written.append(str(path))
    return 0


def _interrupted(stderr) -> int:
    sigint.leaving()
    try:
        print(INTERRUPTED_LINE, file=stderr, flush=True)
    except (KeyboardInterrupt, OSError, ValueError):
        pass
    return EXIT_INTERRUPTED


def _main(argv, stdout, stderr) -> int:
    args = build_parser().parse_args(argv)
    args.written = []  # output files completed so far (said if a later one fails)
    import plant
    from plant.logs.fileio import OutputFileError

    try:
        return _run(args, stdout, stderr)
    except (CLIError, OutputFileError, plant.LogError, plant.SimulationError, ValueError,
            OSError) as e:
        if _is_wrapped_interrupt(e):
            return _interrupted(stderr)
        done = f" (written before the failure: {', '.join(args.written)})" if args.written else ""
        print(f"error: {_one_line(e)}{done}", file=stderr)
        return 1


def main(argv=None) -> int:
    """Entry point of ``python -m identification`` and ``puma-identify``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 success, 1 bad log, option or output path (one
        ``error:`` line on stderr, no output file), 2 usage error (raised by
        argparse as ``SystemExit``), 130 interrupted (the best result so far
        is written if there is one; otherwise the one line
        :data:`INTERRUPTED_LINE`, never a traceback).
    """
    stdout, stderr = sys.stdout, sys.stderr
    installed = sigint.install()  # False under python -m identification (done before imports)
    try:
        return _main(argv, stdout, stderr)
    except KeyboardInterrupt:
        return _interrupted(stderr)
    except Exception as e:  # e.g. numba's SystemError around a KeyboardInterrupt
        if not _is_wrapped_interrupt(e):
            raise
        return _interrupted(stderr)
    finally:
        if installed:  # a call in-process: leave the caller's handlers as they were
            sigint.uninstall()
