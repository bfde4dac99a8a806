"""``python -m identification`` and the ``puma-identify`` script: see :mod:`identification.cli`.

A Ctrl-C at any time, also while the command-line module and its
dependencies are being imported, ends with one line on stderr and exit
status 130, never a traceback.
"""
import gc
import sys

#: Exit status of a run stopped by Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130


def main(argv=None):
    """Run the command line (see :func:`identification.cli.main`).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status (0, 1, 130; argparse usage errors exit with 2).
    """
    return _main(argv, process=False)


def _main(argv, process):
    """:func:`main`; ``process``: the command owns the process (watchdog, handlers kept)."""
    installed = False
    try:
        try:
            from identification import sigint

            # a Ctrl-C swallowed by a finaliser or cleared by C code is remembered, not
            # lost; in a process of its own a run stuck after a Ctrl-C is ended by the
            # watchdog
            installed = sigint.install(watchdog=process)
            from identification.cli import main as cli_main
        except KeyboardInterrupt:
            from identification import sigint

            sigint.leaving()
            try:
                print("error: interrupted (nothing written)", file=sys.stderr, flush=True)
            except (KeyboardInterrupt, OSError, ValueError):
                pass
            return EXIT_INTERRUPTED
        return cli_main(argv)
    finally:
        if installed and not process:  # a call in-process: the caller's handlers again
            sigint.uninstall()


def exit_after(status):
    """Leave the process with ``status``, skipping the final garbage collection.

    The compiled kernels leave many objects behind (numba's typing and LLVM
    records); collecting them at interpreter exit took 0.3-0.8 s of a
    command that ends anyway.  :func:`gc.freeze` moves them out of the
    collector's reach; the process then ends as usual (files closed, atexit
    handlers run).  Only for the command line, never inside a library call.

    Parameters
    ----------
    status : int
        Exit status.
    """
    gc.freeze()
    if status == EXIT_INTERRUPTED:
        from identification import sigint

        sigint.leaving()
        # a Ctrl-C: every output is complete or absent by now (atomic writes); leave at
        # once, so that the interpreter's shutdown cannot turn a KeyboardInterrupt it
        # saw on the way into a death by SIGINT (exit status -2 instead of 130)
        import os

        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, KeyboardInterrupt):
                pass
        os._exit(EXIT_INTERRUPTED)
    sys.exit(status)


def script():
    """Entry point of the ``puma-identify`` script: :func:`main`, then :func:`exit_after`."""
    exit_after(_main(None, process=True))


if __name__ == "__main__":
    exit_after(_main(None, process=True))
