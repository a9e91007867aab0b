"""The one place an error becomes a message: every exception that reaches
:func:`run_safely` is printed as one line on stderr, ``popbench: error: …``, with exit status 2
for bad input (a malformed file, an unknown dataset, a wrong checksum, an option out of range, a
usage error) and 1 for runtime failures (a download that failed, an unexpected exception;
``POPBENCH_DEBUG=1`` shows its traceback)."""

from __future__ import annotations

import os
import sys

import typer

from popbench.errors import PopbenchError

EXIT_BAD_INPUT = 2
EXIT_RUNTIME = 1
EXIT_INTERRUPTED = 130


class RuntimeFailure(Exception):
    """A command that ran but failed (exit status 1), with a one-line message."""


class Interrupted(Exception):
    """A Ctrl-C that a command caught to say what it saved (exit status 130). typer turns a
    KeyboardInterrupt raised in a command into a bare exit status, dropping its message."""


def one_line(text: str) -> str:
    """``text`` with every run of whitespace (newlines included) made one space."""
    return " ".join(str(text).split())


def error_exit(error: BaseException) -> tuple[str, int]:
    """The one-line message and exit status for an exception that reached :func:`run_safely`."""
    from popbench.datasets import DatasetUnavailableError

    if isinstance(error, typer.TyperException):  # usage errors from the parser
        where = getattr(getattr(error, "ctx", None), "command_path", "popbench")
        return f"{error.format_message()} (see `{where} --help`)", error.exit_code
    if isinstance(error, DatasetUnavailableError | RuntimeFailure):
        return str(error), EXIT_RUNTIME
    if isinstance(error, PopbenchError | ValueError):
        return str(error), EXIT_BAD_INPUT
    if isinstance(error, OSError) and error.filename is not None:
        return f"{error.strerror}: {error.filename}", EXIT_BAD_INPUT
    detail = f"{type(error).__name__}: {error}"
    return f"internal error ({detail}); set POPBENCH_DEBUG=1 for the traceback", EXIT_RUNTIME


def run_safely(app: typer.Typer, argv: list[str] | None) -> int:
    """Run the typer ``app`` on ``argv`` (None: ``sys.argv``) and return its exit status; every
    error becomes one ``popbench: error: …`` line on stderr (:func:`error_exit`)."""
    try:
        code = app(args=argv, prog_name="popbench", standalone_mode=False)
    except typer.Abort:
        sys.stderr.write("popbench: aborted\n")
        return EXIT_RUNTIME
    except (KeyboardInterrupt, Interrupted) as error:
        detail = f" ({error})" if str(error) else ""
        sys.stderr.write(f"popbench: interrupted{detail}\n")
        return EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - the one place errors become a message
        if os.environ.get("POPBENCH_DEBUG"):
            raise
        message, code = error_exit(error)
        sys.stderr.write(f"popbench: error: {one_line(message)}\n")
        return code
    return code if isinstance(code, int) else 0
